"""The hostile-input corpus (issue 26 "Bad files", issue 28 "One line for every mistake"):
inputs written to break thermocomp's loaders, and the bounded runner that feeds them to the
real command line."""

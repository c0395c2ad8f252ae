"""The two-link run kind (the thesis's bench): one step = model -> target check -> move ->
measure -> record."""

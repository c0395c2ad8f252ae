"""The HTTP face of thermocomp: REST, WebSocket, dashboard; and the process entry point."""

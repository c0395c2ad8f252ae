"""The CRS C500C controller's two links: the `ash` console over RS-232 (robot, link, console,
protocol and its texts, replies, position read-out, commands; docs/reference/c500c-console.md)
and the fast path to the thermocomp program on the controller's second port (server,
server_link, server_protocol; controller/PROTOCOL.md), with each link's bring-up check."""

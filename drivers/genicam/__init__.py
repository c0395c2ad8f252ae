"""GenICam cameras (GigE Vision, USB3 Vision) through pypylon: the transport, the spot camera
and the radiometric IR camera, and the feature nodes they set."""

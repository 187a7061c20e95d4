"""Commercial wearables' public BLE protocols, as byte layouts: what their devices send and accept.

One module per vendor protocol, each with its GATT UUIDs, the encodings of its commands, replies and
data notifications (decoders for the client, encoders for the simulated device) and its sources: the
vendor's published specification or SDK, cited in the module docstring and in the tests that check the
decoders against the vendor's own example bytes.
"""

"""The simulated gyrocal wearable: a GATT peripheral streaming the wearable protocol from calib's
simulator (a scripted clinician, with faults) or a recorded CSV, and a simulated BlueZ that serves it
to the real bleak client over a private D-Bus (docs/protocol.md).

Depends only on ``wearable_protocol`` and calib (the simulator, and the CSV reader for replays).
"""

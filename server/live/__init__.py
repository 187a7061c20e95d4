"""The live path: a wearable's samples through the guided session's state machine (session), run by the
runner (runner) against the device's link, with its events streamed to the page (events) in plain words
(guidance)."""

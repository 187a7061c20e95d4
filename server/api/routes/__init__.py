"""One APIRouter per resource: health, auth, devices, sessions, write_back (a calibration written to the wearable),
identify (a wearable asked which one it is),
audit, plots (a session's before/after traces) and diagnosis (the model check)."""

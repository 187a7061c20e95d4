"""One APIRouter per resource: health, auth, devices, sessions, audit, plots (a session's before/after traces)
and diagnosis (the model check)."""

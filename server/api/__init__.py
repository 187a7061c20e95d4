"""The HTTP API: one router per resource (routes/), what the routes show of devices and sessions (views),
and the wizard page's files (page)."""

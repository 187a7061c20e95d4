"""gyrocal webui package."""

"""gyrocal server package."""

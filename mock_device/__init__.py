"""gyrocal mock_device package."""

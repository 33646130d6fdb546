"""SCPI: the codec (pure functions between commands and text), dialects (data), the cycler driver."""

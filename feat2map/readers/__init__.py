"""Readers of third-party HD map formats into the feat2map model."""

"""slamobs pipeline: readers -> alignment -> observers -> writers -> evaluation."""

__version__ = "0.1.0"

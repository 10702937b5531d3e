"""The installed slamobs version, in a module that imports nothing, so every layer can state it."""

__version__ = "0.1.0"

"""Importers: public datasets converted to logs that every slamobs command reads."""

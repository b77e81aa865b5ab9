"""Lens analysis: paraxial data, spot diagrams, pupils."""

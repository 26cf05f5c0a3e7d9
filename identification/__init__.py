"""Preprocessing (thesis 5.1, 5.2) and integral SINDy identification (thesis 5.3)."""

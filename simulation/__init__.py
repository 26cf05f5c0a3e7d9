"""Simulator of the Husky A200, the laser-tracker campaign and degraded GNSS (data contract writer)."""

"""Tests, mirroring the packages; shared builders live in :mod:`tests.support`."""

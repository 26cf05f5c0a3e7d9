"""The benchmark of the estimators against the campaign's truth under degraded GNSS."""

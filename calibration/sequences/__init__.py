"""Test sequences shipped with rimu (TOML data files, see :mod:`calibration.sequence`)."""

"""Tests of toolkit.config, one file per module of the package."""

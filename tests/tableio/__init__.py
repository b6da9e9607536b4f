"""Tests of toolkit.tableio, one file per module of the package."""

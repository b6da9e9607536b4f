"""Message definitions and table schemas (installed as toolkit.schemas)."""

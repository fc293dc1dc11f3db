"""Broker drivers: one module per broker type behind :class:`engine.drivers.base.Driver`,
registered through the entry-point group ``plantkg.drivers`` (see docs/drivers.md)."""

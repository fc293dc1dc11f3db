"""plantkg knowledge-graph layer: load, validate, query and export the plant graph."""

"""plantkg engine: everything above the knowledge-graph layer (reason, derive, plan, apply, agents,
drivers, CLI). It imports :mod:`kg`; :mod:`kg` never imports it (an import-linter contract)."""

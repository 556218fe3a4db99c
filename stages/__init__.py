"""Processing stages: one module per stage, each with a module-level ``STAGE = Stage(...)``."""

"""A tiny stage package for engine tests: cheap stages with the real engine contracts."""

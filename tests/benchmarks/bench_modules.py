"""Import a script of ``benchmarks/`` by path: it is not a package, and its sibling modules
are only on ``sys.path`` when the script itself runs."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

__all__ = ["load_benchmark"]

_BENCHMARKS = Path(__file__).resolve().parents[2] / "benchmarks"


def load_benchmark(filename: str) -> ModuleType:
    """The module ``benchmarks/<filename>``, loaded under the name ``_bench_<stem>``."""
    path = _BENCHMARKS / filename
    spec = importlib.util.spec_from_file_location(f"_bench_{path.stem.lstrip('_')}", path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    # registered before it runs, as importlib's own recipe does: a dataclass of the script
    # looks its module up in sys.modules (bench_untouched_depth.py has some)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module

"""arroyo: stereo pairs of rock fields to depth maps, rock masks, descriptors and a scene graph.

The engine lives here; processing stages live in the sibling ``stages`` package (or a
package of your own: ``arroyo run --stage-package``, README "Stages"). The library
functions behind the command line (``docs/design.md``):

- :func:`pipeline.runner.run` (``arroyo run``), :func:`pipeline.status.status`,
  :func:`pipeline.graph.describe_graph`;
- :func:`pipeline.synth.synthesize_archive`, :func:`pipeline.evaluate.evaluate_run`;
- :func:`pipeline.query.open_runs`, :func:`pipeline.query.query_runs`,
  :func:`pipeline.query.query_df`, :func:`pipeline.query.frame_dataset` (notebooks,
  ``docs/query.md``); :func:`pipeline.report.build_report`;
- declarations for stage packages: :mod:`pipeline.stage` (``Stage``, ``Param``,
  ``Product``, ``StageResult``, ``FrameContext``).

Submodules are imported on use, so ``import pipeline`` stays cheap.
"""

from __future__ import annotations

__all__ = ["__version__"]

__version__ = "0.1.0"

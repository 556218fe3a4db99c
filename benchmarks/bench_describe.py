"""Descriptor and relation accuracy of the describe stage.

Renders pairs with ``pipeline.synth.pair.render_pair`` and runs
:func:`stages.describe.describe_frame` on

* ``--inputs truth``: the truth labels, disparity, range and height (only the describe
  stage's own errors);
* ``--inputs depth``: truth labels with the depth stage's disparity, range, height and ground
  plane (describe + matching errors);
* ``--inputs pipeline``: depth stage + segment stage (objects matched to truth rocks at
  IoU >= 0.5 with ``pipeline.metrics.match_objects``).
* ``--rundir DIR [DIR ...]``: the depth and segment products of finished ``arroyo run``
  directories of archives with truth, described again with the current code and
  ``--set describe.PARAM=VALUE`` overrides, scored like ``arroyo evaluate`` (same matching,
  same rock table). The products stay fixed, so describe changes can be compared while the
  depth and segment stages change underneath (copy a run directory to freeze it). Columns:
  rocks within ``--near`` m (median width error, class accuracy, median |height error| of
  ``height_max_m``, median range error), all matched rocks, relation agreement, relation
  rows per frame, CPU ms per frame of ``describe_frame`` alone; then the near rocks split
  by the truth's ``touches_border``: rocks seen whole (interior) and rocks cut by the image
  border, whose truth is of the whole rock while only part of it is visible; last the signed
  median width error of the near rocks (the median |error| hides a bias).
  ``--labels truth`` / ``--depth truth`` describe the truth labels / the truth disparity,
  range and height instead of the run's; ``--labels segment`` segments every frame again
  with the current segment code (the run's depth products, the catalog's current
  ``[params.segment]`` as ``bench_segment.py --rundir`` reads them, plus ``--set
  segment.PARAM=VALUE``), so a segmentation change is measured on the widths; ``--dump
  CSV`` writes one row per matched rock (descriptors, ``t_`` truth columns, IoU and mask
  pixel counts); ``--decompose`` scores the same rocks (matched by the run, near, seen
  whole; pooled per archive) with each of the four combinations, which splits the error
  between segmentation, depth and describe.

Scores against the truth rocks with ``pipeline.metrics`` (rocks within ``--near`` m of the
camera for the descriptor targets; relations between matched rocks).

``--set STAGE.PARAM=VALUE`` (repeated) sets a parameter of a stage the mode runs, parsed and
checked like ``arroyo run --set`` (an unknown one is an error that lists the stage's
parameters; ``benchmarks/_overrides.py``): ``describe.*``, ``depth.*`` with
``--inputs depth`` or ``pipeline``, ``segment.*`` with ``--inputs pipeline``; ``--rundir``
keeps the run's depth and segment products, so it takes ``describe.*`` only (and
``segment.*`` with ``--labels segment``), and
``--stage-speed`` runs every stage with its defaults and takes none.

Usage::

    PYTHONPATH=. .venv/bin/python benchmarks/bench_describe.py --frames 4 --inputs truth
    PYTHONPATH=. .venv/bin/python benchmarks/bench_describe.py --inputs depth \
        --set depth.subpixel=parabola --set describe.sample_max_m=0.12
    PYTHONPATH=. .venv/bin/python benchmarks/bench_describe.py --stage-speed  # CPU ms/frame
    PYTHONPATH=. .venv/bin/python benchmarks/bench_describe.py --rundir runs/lab runs/lava \
        --set describe.relation_radius_m=1e6
    PYTHONPATH=. .venv/bin/python benchmarks/bench_describe.py --labels segment \
        --rundir runs/eval/lava --set segment.face_bands=0   # widths of new masks
    PYTHONPATH=. .venv/bin/python benchmarks/bench_describe.py --decompose \
        --rundir runs/eval/lab runs/eval/mojave runs/eval/lava
"""

from __future__ import annotations

import argparse
import time

import numpy as np

# sibling modules: benchmarks/ is on sys.path when one of its scripts runs
from _overrides import depth_products, stage_overrides
from _rundir import open_run

from pipeline.camera import Camera
from pipeline.errors import ParamError
from pipeline.metrics import (
    descriptor_errors,
    match_objects,
    relation_agreement,
    true_occlusions,
)
from pipeline.stage import FrameContext
from pipeline.synth.pair import render_pair
from stages import describe as describe_stage
from stages.describe import describe_frame
from stages.segment import segment_image


def _frame(archetype: str, seed: int, size: int, inputs: str, overrides: dict) -> dict:
    """Describe one rendered frame; ``overrides``: stage name to its ``--set`` params."""
    left, right, truth, rocks, cam = render_pair(archetype, seed=seed, size=size)
    camera = Camera(**cam)
    labels = truth["labels"]
    depth = {k: truth[k] for k in ("disparity", "range", "height")}
    plane = None
    if inputs in ("depth", "pipeline"):
        out = depth_products(
            left,
            right,
            camera=camera,
            params=overrides.get("depth"),
            frame_id=f"{archetype}{seed}",
            archive=archetype,
        )
        depth = {k: out[k] for k in ("disparity", "range", "height")}
        plane = out["ground_plane"]
    if inputs == "pipeline":
        from stages import segment as segment_stage

        frame = FrameContext(frame_id=f"{archetype}{seed}", archive=archetype, camera=camera)
        labels = segment_stage.STAGE.run(
            {"right": right, "disparity": depth["disparity"], "height": depth["height"]},
            frame=frame,
            params=segment_stage.STAGE.resolve_params(overrides.get("segment", {})),
        ).arrays["labels"]
    start = time.perf_counter()
    desc, rel, figures = describe_frame(
        labels,
        right,
        depth["disparity"],
        depth["range"],
        depth["height"],
        camera=camera,
        ground_plane=plane,
        **overrides.get("describe", {}),
    )
    seconds = time.perf_counter() - start
    if inputs == "pipeline":
        matches = match_objects(labels, truth["labels"])
        rock_of = dict(zip(matches.pred_ids.tolist(), matches.true_ids.tolist(), strict=True))
    else:
        rock_of = {int(i): int(i) for i in desc["object_id"]}
    keep = np.array([int(i) in rock_of for i in desc["object_id"]], dtype=bool)
    desc = {k: v[keep] for k, v in desc.items()}
    rkeep = np.array(
        [
            int(s) in rock_of and int(o) in rock_of
            for s, o in zip(rel["subject_id"], rel["object_id"], strict=True)
        ],
        dtype=bool,
    )
    rel = {k: v[rkeep] for k, v in rel.items()}
    rel["subject_id"] = np.array([rock_of[int(i)] for i in rel["subject_id"]], dtype=np.int64)
    rel["object_id"] = np.array([rock_of[int(i)] for i in rel["object_id"]], dtype=np.int64)
    desc["object_id"] = np.array([rock_of[int(i)] for i in desc["object_id"]], dtype=np.int64)
    by_id = {r["rock_id"]: r for r in rocks}
    ids = desc["object_id"].tolist()
    truth_cols = {
        name: np.array([by_id[i][name] for i in ids])
        for name in ("height_m", "width_m", "range_m", "size_class", "x_m", "y_m", "extent_x_m")
    }
    occ = true_occlusions(truth["labels"], truth["range"])
    subj = [by_id[i] for i in rel["subject_id"].tolist()]
    obj = [by_id[i] for i in rel["object_id"].tolist()]
    occludes_truth = np.array(
        [(s["rock_id"], o["rock_id"]) in occ for s, o in zip(subj, obj, strict=True)],
        dtype=bool,
    )
    return {
        "desc": desc,
        "truth": truth_cols,
        "relation": rel["relation"],
        "subject": {k: np.array([s[k] for s in subj]) for k in ("x_m", "y_m")},
        "object": {k: np.array([o[k] for o in obj]) for k in ("x_m", "y_m")},
        "occludes_truth": occludes_truth,
        "seconds": seconds,
        "k": figures["sfd_k"],
    }


def _cat(frames: list[dict], key: str) -> dict:
    parts = [f[key] for f in frames]
    names = parts[0].keys()
    return {n: np.concatenate([p[n] for p in parts]) for n in names}


def _as_rows(columns: dict) -> list[dict]:
    """Column arrays of one frame's table as the row dicts ``pipeline.evaluate`` reads."""
    names = list(columns)
    return [dict(zip(names, values, strict=True)) for values in zip(*columns.values(), strict=True)]


def _rundir_scores(
    rundir: str,
    overrides: dict,
    near: float,
    *,
    labels_from: str = "run",
    depth_from: str = "run",
    dump: list | None = None,
    segment_overrides: dict | None = None,
) -> dict:
    """Describe every frame of a finished run again and score it like ``arroyo evaluate``.

    ``labels_from`` / ``depth_from`` = ``'truth'`` swap the run's labels / disparity, range
    and height for the truth's (to split an error between segmentation, matching and the
    describe stage's own rules); ``labels_from = 'segment'`` segments the frame again with
    the current code, ``run.segment_params()`` and ``segment_overrides``; ``dump`` collects
    one dict per matched rock (the descriptor row, ``t_``-prefixed truth columns, the pair's
    IoU and pixel counts).
    """
    from pipeline.evaluate import (
        _PRED_COLUMNS,
        _TRUE_COLUMNS,
        _columns,
        _edges,
        _pair_columns,
        _relation_scores,
    )

    run = open_run(rundir)
    camera = run.camera
    segment_params = {**run.segment_params(), **(segment_overrides or {})}
    pairs: tuple[list, list] = ([], [])
    edges: dict[str, list] = {}
    n_rel, n_frames, cpu = 0, 0, 0.0
    for frame in run.frames():
        truth_labels = frame.truth["labels"]
        labels = frame.product("labels").astype(np.int32)
        if labels_from == "truth":
            labels = truth_labels
        elif labels_from == "segment":
            labels = segment_image(
                frame.product(camera.reference),
                height=frame.product("height"),
                disparity=frame.product("disparity"),
                **segment_params,
            ).labels
        arrays = [
            frame.truth[name]
            if depth_from == "truth" and name in ("disparity", "range", "height")
            else frame.product(name)
            for name in (camera.reference, "disparity", "range", "height", "ground_plane")
        ]
        start = time.process_time()  # describe only: the products are read before
        desc, rel, _ = describe_frame(
            labels, *arrays[:4], camera=camera, ground_plane=arrays[4], **overrides
        )
        cpu += time.process_time() - start
        n_rel += rel["subject_id"].size
        n_frames += 1
        # score with arroyo evaluate's own pairing and edge helpers, on the same row dicts
        rocks_by_id = {int(r["rock_id"]): r for r in frame.rocks}
        matches = match_objects(labels, truth_labels)
        p_rows, t_rows = _pair_columns(matches, _as_rows(desc), rocks_by_id)
        if dump is not None:
            _dump_rows(
                dump,
                (rundir, run.archive, frame.frame_id),
                matches,
                desc,
                rocks_by_id,
                labels,
                truth_labels,
            )
        pairs[0].extend(p_rows)
        pairs[1].extend(t_rows)
        occlusions = true_occlusions(truth_labels, frame.truth["range"])
        for key, values in _edges(_as_rows(rel), matches, rocks_by_id, occlusions).items():
            edges.setdefault(key, []).extend(values)
    p_cols = _columns(pairs[0], _PRED_COLUMNS)
    t_cols = _columns(pairs[1], _TRUE_COLUMNS)
    err = descriptor_errors(p_cols, t_cols, near_range_m=near)
    agreement = _relation_scores(edges)
    with np.errstate(divide="ignore", invalid="ignore"):
        signed = p_cols["width_m"] / t_cols["width_m"] - 1
    near_rocks = t_cols["range_m"] <= near
    return {
        "archive": run.archive,
        "err": err,
        # the median |error| hides a bias: a width biased low and one biased high score alike
        "signed": float(np.nanmedian(signed[near_rocks])) if near_rocks.any() else np.nan,
        "rel": agreement["agreement"],
        "rows": n_rel / max(n_frames, 1),
        "ms": 1000 * cpu / max(n_frames, 1),
    }


def _dump_rows(
    out: list,
    where: tuple[str, str, str],
    matches,
    desc: dict,
    rocks_by_id: dict,
    labels: np.ndarray,
    truth_labels: np.ndarray,
) -> None:
    """Append one row per matched rock: descriptors, ``t_`` truth columns, IoU, pixel counts.

    ``pred_px``, ``true_px``, ``both_px``: pixels of the object, of the truth rock and of both
    (mask recall = both / true, precision = both / pred).
    """
    row_of = {int(i): k for k, i in enumerate(desc["object_id"].tolist())}
    for n, (p, t) in enumerate(
        zip(matches.pred_ids.tolist(), matches.true_ids.tolist(), strict=True)
    ):
        if p not in row_of or t not in rocks_by_id:
            continue
        row = dict(zip(("rundir", "archive", "frame_id"), where, strict=True))
        row.update({k: v[row_of[p]] for k, v in desc.items()})
        row.update({f"t_{k}": v for k, v in rocks_by_id[t].items() if k != "frame_id"})
        pm, tm = labels == p, truth_labels == t
        row["pred_px"] = int(pm.sum())
        row["true_px"] = int(tm.sum())
        row["both_px"] = int((pm & tm).sum())
        row["iou"] = float(matches.iou[n])
        out.append(row)


def _rundir_main(
    rundirs: list[str],
    overrides: dict,
    near: float,
    *,
    labels_from: str = "run",
    depth_from: str = "run",
    dump_path: str | None = None,
    segment_overrides: dict | None = None,
) -> None:
    print(
        f"{'archive':9} {'rocks':>5} {'near':>5} {'dw/w':>6} {'class':>6} {'|dh| m':>7} "
        f"{'dr/r':>6} {'all dw/w':>8} {'all cls':>7} {'rel':>6} {'rows/fr':>8} {'cpu ms':>7} "
        f"| {'interior':>8} {'dw/w':>6} {'class':>6} | {'border':>6} {'dw/w':>6} {'class':>6} "
        f"| {'sgn dw/w':>8}"
    )
    dump: list | None = [] if dump_path else None
    for rundir in rundirs:
        r = _rundir_scores(
            rundir,
            overrides,
            near,
            labels_from=labels_from,
            depth_from=depth_from,
            dump=dump,
            segment_overrides=segment_overrides,
        )
        e = r["err"]
        split = " | ".join(
            f"{e.get(f'near_{part}_n_rocks', float('nan')):{w}.0f} "
            f"{e.get(f'near_{part}_width_rel_err_median', float('nan')):6.3f} "
            f"{e.get(f'near_{part}_class_accuracy', float('nan')):6.3f}"
            for part, w in (("interior", 8), ("border", 6))
        )
        print(
            f"{r['archive']:9} {int(e['n_rocks']):5d} {int(e['near_n_rocks']):5d} "
            f"{e['near_width_rel_err_median']:6.3f} {e['near_class_accuracy']:6.3f} "
            f"{e['near_height_abs_err_median_m']:7.4f} {e['near_range_rel_err_median']:6.4f} "
            f"{e['width_rel_err_median']:8.3f} {e['class_accuracy']:7.3f} {r['rel']:6.3f} "
            f"{r['rows']:8.0f} {r['ms']:7.1f} | {split} | {r['signed']:+8.3f}"
        )
    if dump_path and dump is not None:
        import pyarrow as pa
        import pyarrow.csv as pacsv

        pacsv.write_csv(pa.Table.from_pylist(dump), dump_path)
        print(f"wrote {len(dump)} matched rocks to {dump_path}")


_COMBOS = (("run", "run"), ("truth", "run"), ("run", "truth"), ("truth", "truth"))
"""(labels, depth) sources of ``--decompose``: the pipeline, then each input made perfect."""


def _decompose_main(rundirs: list[str], overrides: dict, near: float) -> None:
    """Width error and class accuracy of the same rocks with each input swapped for truth.

    The rocks are those the run's own objects match (IoU >= 0.5) within ``near`` m and not
    cut by the image border, pooled per archive over ``rundirs``. Swapping the labels and/or
    the depth products for the truth's splits the error between segmentation, depth and the
    describe stage's own rules (truth labels and truth depth).
    """
    # the class limit the describe stage ran with: the override, else the stage's default
    limit = float(overrides.get("sample_max_m", describe_stage.STAGE.defaults()["sample_max_m"]))
    dumps: dict[tuple[str, str], list] = {combo: [] for combo in _COMBOS}
    for labels_from, depth_from in _COMBOS:
        for rundir in rundirs:
            _rundir_scores(
                rundir,
                overrides,
                near,
                labels_from=labels_from,
                depth_from=depth_from,
                dump=dumps[labels_from, depth_from],
            )

    def key(row: dict) -> tuple:
        return row["rundir"], row["frame_id"], int(row["t_rock_id"])

    by_key = {combo: {key(r): r for r in rows} for combo, rows in dumps.items()}
    base = [r for r in dumps["run", "run"] if r["t_range_m"] <= near and not r["t_touches_border"]]
    print(
        "median |width error| (signed median) and class accuracy of the same rocks "
        f"(matched by the run, within {near:g} m, seen whole) with labels/depth from run or truth"
    )
    print(
        f"{'archive':8} {'rocks':>5} "
        + " ".join(f"{lab + '/' + dep:>22}" for lab, dep in _COMBOS)
        + f" {'recall':>6} {'prec':>5} {'iou':>5} | {'<=1cm':>5} {'cls':>5} {'other':>5}"
    )
    for archive in sorted({r["archive"] for r in base}):
        rows = [r for r in base if r["archive"] == archive]
        cells = []
        for combo in _COMBOS:
            pairs = [(by_key[combo].get(key(r)), r) for r in rows]
            err = np.array([p["width_m"] / r["t_width_m"] - 1 if p else np.nan for p, r in pairs])
            ok = np.array([bool(p) and p["size_class"] == r["t_size_class"] for p, r in pairs])
            cells.append(
                f"{np.nanmedian(np.abs(err)):6.3f} ({np.nanmedian(err):+6.3f}) {ok.mean():6.3f}"
            )
        recall = np.median([r["both_px"] / r["true_px"] for r in rows])
        precision = np.median([r["both_px"] / r["pred_px"] for r in rows])
        iou = np.median([r["iou"] for r in rows])
        close = np.array([abs(r["t_width_m"] - limit) <= 0.01 for r in rows])
        ok = np.array([r["size_class"] == r["t_size_class"] for r in rows])
        print(
            f"{archive:8} {len(rows):5d} "
            + " ".join(f"{c:>22}" for c in cells)
            + f" {recall:6.2f} {precision:5.2f} {iou:5.2f} | {int(close.sum()):5d} "
            f"{ok[close].mean() if close.any() else np.nan:5.2f} "
            f"{ok[~close].mean() if (~close).any() else np.nan:5.3f}"
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--archetypes", default="lab,mojave,lava,dunes")
    parser.add_argument("--frames", type=int, default=3)
    parser.add_argument("--size", type=int, default=500)
    parser.add_argument("--near", type=float, default=2.0)
    parser.add_argument("--inputs", choices=("truth", "depth", "pipeline"), default="truth")
    parser.add_argument(
        "--stage-speed",
        action="store_true",
        help="only: CPU ms per frame of the describe stage on depth + segment stage products",
    )
    parser.add_argument("--rundir", nargs="+", help="re-describe finished run directories")
    parser.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="STAGE.PARAM=VALUE",
        dest="overrides",
        help="a stage parameter, checked like arroyo run --set; repeat for more: describe.*, "
        "depth.* with --inputs depth or pipeline, segment.* with --inputs pipeline; none "
        "with --stage-speed",
    )
    parser.add_argument(
        "--labels",
        choices=("run", "truth", "segment"),
        default="run",
        help="with --rundir: describe the run's labels, the truth labels or labels segmented "
        "again with the current code (and --set segment.PARAM=VALUE)",
    )
    parser.add_argument(
        "--depth",
        choices=("run", "truth"),
        default="run",
        help="with --rundir: the run's disparity/range/height or the truth's",
    )
    parser.add_argument("--dump", metavar="CSV", help="with --rundir: one row per matched rock")
    parser.add_argument(
        "--decompose",
        action="store_true",
        help="with --rundir: the same rocks with labels and/or depth from the truth",
    )
    args = parser.parse_args()
    if args.rundir:
        mode, runs = "--rundir (the run's depth and segment products)", ("describe",)
        if args.labels == "segment" and not args.decompose:
            mode, runs = "--rundir --labels segment", ("describe", "segment")
    elif args.stage_speed:
        mode, runs = "--stage-speed (the stages' defaults)", ()
    else:
        mode, runs = f"--inputs {args.inputs}", _INPUT_STAGES[args.inputs]
    try:
        _run(args, stage_overrides(args.overrides, runs=runs, mode=mode))
    except ParamError as error:
        parser.error(str(error))


_INPUT_STAGES = {
    "truth": ("describe",),
    "depth": ("depth", "describe"),
    "pipeline": ("depth", "segment", "describe"),
}
"""The stages ``--inputs`` runs on a rendered pair, whose parameters ``--set`` may change."""


def _run(args: argparse.Namespace, overrides: dict) -> None:
    if args.rundir and args.decompose:
        _decompose_main(args.rundir, overrides.get("describe", {}), args.near)
        return
    if args.rundir:
        _rundir_main(
            args.rundir,
            overrides.get("describe", {}),
            args.near,
            labels_from=args.labels,
            depth_from=args.depth,
            dump_path=args.dump,
            segment_overrides=overrides.get("segment", {}),
        )
        return
    if args.stage_speed:
        from bench_segment import stage_speed  # sibling script (benchmarks/ is on sys.path)

        stage_speed(args.archetypes.split(","), args.frames, args.size, 3, stages=("describe",))
        return
    print(
        f"{'archetype':9} {'rocks':>5} {'near':>5} {'|dh|max':>8} {'|dh|top':>8} "
        f"{'dw/w':>6} {'dw/wx':>6} {'dr/r':>6} {'class':>6} {'rel':>6} {'occl':>6} {'ms':>6}"
    )
    for archetype in args.archetypes.split(","):
        frames = [
            _frame(archetype, seed, args.size, args.inputs, overrides)
            for seed in range(args.frames)
        ]
        desc = _cat(frames, "desc")
        truth = _cat(frames, "truth")
        err = descriptor_errors(desc, truth, near_range_m=args.near)
        near = truth["range_m"] <= args.near
        wx = np.nanmedian(np.abs(desc["width_m"][near] / truth["extent_x_m"][near] - 1))
        rel = relation_agreement(
            np.concatenate([f["relation"] for f in frames]),
            _cat(frames, "subject"),
            _cat(frames, "object"),
            occludes_truth=np.concatenate([f["occludes_truth"] for f in frames]),
        )
        ms = 1000 * np.mean([f["seconds"] for f in frames])
        print(
            f"{archetype:9} {desc['object_id'].size:5d} {int(near.sum()):5d} "
            f"{err['near_height_abs_err_median_m']:8.4f} "
            f"{err['near_study_height_abs_err_median_m']:8.4f} "
            f"{err['near_width_rel_err_median']:6.3f} {wx:6.3f} "
            f"{err['near_range_rel_err_median']:6.4f} {err['near_class_accuracy']:6.3f} "
            f"{rel['agreement']:6.3f} {rel.get('agreement_occludes', float('nan')):6.3f} "
            f"{ms:6.1f}"
        )


if __name__ == "__main__":
    main()

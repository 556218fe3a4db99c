"""Staged parts and published generations of the Parquet table products."""

from __future__ import annotations

import os

import pyarrow as pa
import pyarrow.dataset as ds
import pyarrow.parquet as pq

from pipeline.tables import publish_table, published_path, write_part

_SCHEMA = pa.schema(
    [
        ("archive", pa.string()),
        ("run_id", pa.string()),
        ("frame_id", pa.string()),
        ("object_id", pa.int32()),
        ("value", pa.float64()),
    ]
)


def _rows(frame_id: str, ids: list[int], value: float) -> pa.Table:
    n = len(ids)
    return pa.table(
        {
            "archive": ["arch"] * n,
            "run_id": ["r1"] * n,
            "frame_id": [frame_id] * n,
            "object_id": pa.array(ids, pa.int32()),
            "value": [value] * n,
        }
    )


def test_publish_keeps_live_rows_in_catalog_order_and_swaps_generations(tmp_path):
    old = write_part(tmp_path, "rocks", _rows("f1", [2, 1], 0.0))  # f1's first attempt
    new = write_part(
        tmp_path, "rocks", pa.concat_tables([_rows("f1", [1], 1.0), _rows("f0", [3, 1, 2], 1.0)])
    )
    parts = [(old[0], old[1]), (new[0], new[1])]
    live = {"f0": new[0], "f1": new[0]}
    order = {"f0": 0, "f1": 1}
    link = publish_table(
        tmp_path, "rocks", "arch", live, parts, _SCHEMA, order, max_rows_per_file=2
    )
    assert link == published_path(tmp_path, "rocks") and link.is_symlink()
    files = sorted(link.rglob("*.parquet"))
    assert [f.name for f in files] == ["part-0.parquet", "part-1.parquet"]  # 4 rows, 2 per file
    table = ds.dataset(link, partitioning="hive").to_table()
    rows = [(r["frame_id"], r["object_id"], r["value"]) for r in table.to_pylist()]
    assert rows == [("f0", 1, 1.0), ("f0", 2, 1.0), ("f0", 3, 1.0), ("f1", 1, 1.0)]
    assert set(table["archive"].to_pylist()) == {"arch"}  # from the directory name only
    assert "archive" not in pq.read_schema(files[0]).names
    first = os.readlink(link)
    publish_table(tmp_path, "rocks", "arch", live, parts, _SCHEMA, order)
    second = os.readlink(link)
    publish_table(tmp_path, "rocks", "arch", live, parts, _SCHEMA, order)
    generations = {p.name for p in (tmp_path / ".published").iterdir()}
    # the current and the previous generation stay (a reader may have just listed it)
    assert first not in generations and generations == {
        os.path.basename(second),
        os.path.basename(os.readlink(link)),
    }


def test_an_empty_table_still_publishes_one_typed_file(tmp_path):
    link = publish_table(tmp_path, "rocks", "arch", {}, [], _SCHEMA, {})
    (only,) = link.rglob("*.parquet")
    assert pq.read_table(only).num_rows == 0
    assert pq.read_schema(only).field("value").type == pa.float64()

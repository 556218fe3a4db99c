#!/usr/bin/env bash
# Accuracy of the whole pipeline on every shipped archive, against ground truth and the
# baselines (OpenCV StereoSGBM, Otsu), plus the README's three example queries.
#   bash benchmarks/evaluate_archives.sh [OUTDIR]      (default runs/eval)
set -euo pipefail
cd "$(dirname "$0")/.."
out="${1:-runs/eval}"
arroyo="${ARROYO:-arroyo}"
for archive in lab mojave lava dunes; do
    "$arroyo" run "catalogs/$archive.toml" --out "$out/$archive" --quiet
    "$arroyo" evaluate "$out/$archive"
done
"$arroyo" query "$out/lab" "$out/mojave" "$out/lava" "$out/dunes" \
    "SELECT archive, count(*) FILTER (WHERE height_max_m > 0.10 AND range_m < 2.0) AS tall_within_2m, count(*) AS all_rocks FROM descriptors GROUP BY archive ORDER BY archive"
"$arroyo" query "$out/lab" "$out/mojave" "$out/lava" \
    "SELECT s.archive, s.frame_id, s.object_id AS sample, o.object_id AS obstacle, round(r.distance_m, 2) AS distance_m FROM descriptors s JOIN relations r ON r.run = s.run AND r.frame_id = s.frame_id AND r.subject_id = s.object_id AND r.relation = 'behind' JOIN descriptors o ON o.run = r.run AND o.frame_id = r.frame_id AND o.object_id = r.object_id WHERE s.size_class = 'sample' AND o.size_class = 'obstacle' AND r.overlap > 0 ORDER BY s.archive, s.frame_id, sample, obstacle LIMIT 8"
"$arroyo" query "$out/lab" "$out/mojave" "$out/lava" "$out/dunes" \
    "SELECT archive, round(avg(describe_rock_count), 1) AS rocks_per_frame, round(avg(describe_rock_area_fraction), 3) AS area_fraction, round(avg(describe_sfd_k), 3) AS sfd_k FROM frames WHERE status = 'done' GROUP BY archive ORDER BY archive"

#!/usr/bin/env bash
# The README's gallery: runs every scene in inputs/ (short end times where a full run is long)
# and renders one still of each into docs/img/gallery/<scene>.png (480x360), then rewrites the
# README block between the gallery markers from the pictures there.
#   bash scripts/gallery.sh [SCENE ...]        default: every inputs/*.toml
#   HPCMPM_GALLERY_RANKS=4 bash scripts/gallery.sh
# Runs go to runs/gallery/<scene> (not committed). The seed-physics scenes run to their own
# end time (the gallery doubles as the check that each does), except the two plug-flow
# channels (t = 3: their Newton solves to t = 10 take 10-15 minutes each).
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
. "$root/scripts/env.sh"
cd "$root"
ranks="${HPCMPM_GALLERY_RANKS:-2}"

# One line per scene; adding a scene's picture is adding its line. Columns: scene (file stem
# in inputs/), end time (- = the scene's own), field to colour by (hpcmpm render --field),
# frame to show (hpcmpm render --frames; -1 = the last), then any other render options.
# A scene in inputs/ without a line is still run (to its own end time, coloured by speed).
TABLE='
bar_2d            5.0    v:x        -1
dam_break_2d      0.4    speed      -1
disks_2d          1.1    speed      -1
jelly_cube_3d     0.4    speed      -1
snow_block_3d     0.15   Jp         -1
sponge_twist_3d   0.5    speed      -1
channel_newtonian_2d   -  v:x     -1
channel_bingham_2d     3  v:x     -1
channel_hb_2d          3  v:x     -1
foam_coil_2d           -  speed   -1
hb_mixer_2d            -  speed   -1
pie_2d                 -  speed   -1
viennetta_2d           -  speed   -1
sponge_twist_ob_3d     -  speed   -1
sponge_bullet_ob_3d    -  speed   -1
toothpaste_3d          -  speed   -1
pd_plate_tear_2d       -  damage  -1
pd_sheet_tear_2d       -  damage  -1
pd_jelly_stretch_3d    -  damage  -1
kalthoff_winkler_2d    -  damage  -1
ibmpm_bar_2d           -  v:x     -1
ibmpm_disk_impact_2d   -  damage  -1
ibmpm_ball_board_3d    -  speed   -1
ibmpm_wall_fracture_2d -  damage  -1
ibmpm_cream_pie_2d     -  damage  9
spb_stretched_bar_2d   -  damage  -1
spb_chocolate_drop_3d  -  damage  -1
cu_shock_column_2d     -  pressure -1
shock_wall_2d          -  pressure -1
taylor_cu_3d           -  eps_p   -1
container_drop_3d      -  eps_p   -1
gelatin_bullet_3d      -  pressure -1
watermelon_3d          -  damage  -1
'

line_of() { awk -v s="$1" '$1 == s { print; exit }' <<<"$TABLE"; }

if [ $# -gt 0 ]; then scenes=("$@"); else
    scenes=(); for f in inputs/*.toml; do scenes+=("$(basename "$f" .toml)"); done
fi
mkdir -p docs/img/gallery
start=$SECONDS
for scene in "${scenes[@]}"; do
    line="$(line_of "$scene")"
    if [ -z "$line" ]; then
        echo "gallery: $scene has no line in scripts/gallery.sh; running it to its own end time"
        line="$scene - speed -1"
    fi
    read -r _ end field frame opts <<<"$line"
    out="runs/gallery/$scene"
    t0=$SECONDS
    until=(); if [ "$end" != - ]; then until=(--end-time "$end"); fi
    mpiexec -n "$ranks" hpcmpm run "inputs/$scene.toml" --out "$out" --force --quiet \
        "${until[@]}" >/dev/null
    rm -rf "$out/still"
    # shellcheck disable=SC2086  # opts is a list of options
    hpcmpm render "$out" --field "$field" --frames "$frame" --size 480x360 --movie none \
        --out "$out/still" --quiet $opts >/dev/null
    cp "$out"/still/render_*.png "docs/img/gallery/$scene.png"
    echo "gallery: docs/img/gallery/$scene.png ($((SECONDS - t0)) s)"
done

# The README block: every picture in docs/img/gallery, three to a row.
python - <<'PY'
import re
from pathlib import Path

pictures = sorted(Path("docs/img/gallery").glob("*.png"))
cells = [f'<td><img src="{p.as_posix()}" width="320" alt="{p.stem}"><br><code>{p.stem}</code></td>'
         for p in pictures]
rows = ["<tr>" + "".join(cells[i:i + 3]) + "</tr>" for i in range(0, len(cells), 3)]
block = "<!-- gallery:start -->\n<table>\n" + "\n".join(rows) + "\n</table>\n<!-- gallery:end -->"
readme = Path("README.md")
text = readme.read_text()
new = re.sub(r"<!-- gallery:start -->.*?<!-- gallery:end -->", lambda m: block, text, flags=re.S)
if new == text and "<!-- gallery:start -->" not in text:
    raise SystemExit("README.md has no gallery markers")
readme.write_text(new)
print(f"gallery: README.md shows {len(pictures)} pictures")
PY
echo "gallery: done in $((SECONDS - start)) s"

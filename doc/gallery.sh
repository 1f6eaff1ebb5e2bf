#!/usr/bin/env bash
# Regenerate doc/gallery.md and its figures (doc/gallery/): every shipped
# system (systems/*.yaml) run as shipped (`mrvi run`, or `mrvi optimize`
# for a file with a `control:` section), with a picture of the motion
# (`mrvi-plot still`, where the model has particles or bodies in 2-D or 3-D)
# and its energy (`mrvi-plot run`) or, for optimal control, the optimal
# trajectory (`mrvi-plot optimize`).  The text of each entry is the first
# paragraph of the system's header comment.
#
# Usage: doc/gallery.sh [BUILD_DIR]       (default: build)
#
# Needs BUILD_DIR/mrvi and Debian's python3-matplotlib and python3-h5py.
# tests/test_docs.sh checks that every shipped system has an entry whose
# figures exist.
set -euo pipefail

root=$(cd "$(dirname "$0")/.." && pwd)
build=$(cd "${1:-$root/build}" && pwd)
mrvi=$build/mrvi
plot=$root/src/cli/mrvi-plot
py=/usr/bin/python3
figs=$root/doc/gallery
work=$build/gallery
[ -x "$mrvi" ] || { echo "no $mrvi: run meson compile -C ${1:-build} first" >&2; exit 1; }
"$py" -c 'import matplotlib, h5py' || { echo "needs python3-matplotlib and python3-h5py" >&2; exit 1; }
rm -rf "$work" "$figs"
mkdir -p "$work" "$figs"

md=$root/doc/gallery.md
{
  echo "# Gallery"
  echo
  echo "Every system shipped in [systems/](../systems/), run as shipped. Each"
  echo "entry shows the motion (\`mrvi-plot still\`: the model at six instants"
  echo "over the traces of every macro node, later instants darker; rigid"
  echo "bodies as their director frames) where the model has particles or"
  echo "bodies in 2-D or 3-D, and the energy (\`mrvi-plot run\`) or, for an"
  echo "optimal control problem, the optimal trajectory (\`mrvi-plot"
  echo "optimize\`). The text is the header of the description file, which"
  echo "says more. Regenerate everything with \`doc/gallery.sh\`"
  echo "([gallery.sh](gallery.sh)); the commands of each entry reproduce it"
  echo "alone."
} >"$md"

for file in "$root"/systems/*.yaml; do
  name=$(basename "$file" .yaml)
  echo "== $name" >&2
  # First paragraph of the header comment.
  about=$(awk '/^#/ { sub(/^# ?/, ""); if ($0 == "") exit; print; next } { exit }' "$file")
  if grep -q '^control:' "$file"; then
    "$mrvi" optimize "$file" -o "$work/$name.h5" -q >/dev/null
    cmd="mrvi optimize systems/$name.yaml -o $name.h5"
    second=trajectory
    "$py" "$plot" optimize "$work/$name.h5" -o "$work" >/dev/null
    # Body terminal conditions only (no coordinate panel): the attitude.
    [ -e "$work/${name}_trajectory.png" ] || second=attitude
  else
    "$mrvi" run "$file" -o "$work/$name.h5" -q --set output.xdmf=false 2>/dev/null
    cmd="mrvi run systems/$name.yaml -o $name.h5"
    second=energy
    "$py" "$plot" run "$work/$name.h5" -o "$work" >/dev/null
  fi
  still=0
  if "$py" "$plot" still "$work/$name.h5" -o "$work" >/dev/null 2>&1; then
    still=1
    cp "$work/${name}_still.png" "$figs/"
  fi
  cp "$work/${name}_$second.png" "$figs/"
  {
    echo
    echo "## $name"
    echo
    echo '```'
    printf '%s\n' "$about"
    echo '```'
    echo
    echo '```sh'
    echo "$cmd"
    [ "$still" -eq 1 ] && echo "mrvi-plot still $name.h5"
    if [ "$second" != energy ]; then
      echo "mrvi-plot optimize $name.h5"
    else
      echo "mrvi-plot run $name.h5"
    fi
    echo '```'
    echo
    [ "$still" -eq 1 ] && echo "![$name: the motion](gallery/${name}_still.png)"
    echo "![$name: $second](gallery/${name}_$second.png)"
  } >>"$md"
done
echo "wrote $md and $(ls "$figs" | wc -l) figures in $figs" >&2

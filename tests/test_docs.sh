#!/usr/bin/env bash
# Keeps the documentation true:
#   - every systems/*.yaml that README.md or doc/*.md names exists and passes
#     `mrvi check`;
#   - every relative link in README.md, doc/*.md and doc/performance/*.md
#     (the measurements' history) points to an existing file or directory
#     (the part before '#'; anchors are not checked); the same files are
#     read by the checks of systems, source paths and anchors below;
#     the checker itself is first shown to fail on a broken link;
#   - the description file printed in doc/tutorial.md is the shipped
#     systems/tutorial_spring.yaml (without its header comment);
#   - doc/*.md cite the paper by equation number, not by LaTeX label
#     (doc/theory.md's translation table excepted);
#   - no file of the repository refers to design notes or directories
#     outside it (the repository must stand alone);
#   - doc/gallery.md has an entry with figures for every systems/*.yaml;
#   - every link to a heading (FILE.md#ANCHOR, #ANCHOR) names one
#     (tests/doc_anchors.py), the checker first shown to fail;
#   - bench/plot_performance.py draws doc/performance.md's figures from
#     doc/results, and takes each idle ratio from the latest run listed;
#   - every command and program whose output README.md and doc/*.md show is
#     re-run and its output compared, numbers within the tolerances stated
#     in tests/doc_outputs.py (timings excepted); the checker is first shown
#     to fail on a changed energy error and to ignore a changed wall time.
#
#   test_docs.sh MRVI_BINARY SOURCE_ROOT
#
# Prints "N passed, M failed" and exits non-zero on any failure.
set -u

mrvi=${1:?usage: test_docs.sh MRVI_BINARY SOURCE_ROOT}
root=${2:?usage: test_docs.sh MRVI_BINARY SOURCE_ROOT}

# shellcheck source=tests/testlib.sh
. "$(dirname "$0")/testlib.sh"

docs=("$root/README.md" "$root"/doc/*.md "$root"/doc/performance/*.md)

# --- description files named by the docs pass `mrvi check` ---
names=$(grep -ohE 'systems/[A-Za-z0-9_.-]+\.yaml' "${docs[@]}" | sort -u)
count=$(printf '%s\n' "$names" | grep -c .)
if [ "$count" -ge 10 ]; then
  pass "docs name $count description files"
else
  fail "docs name only $count description files (expected at least 10)"
fi
for f in $names; do
  if [ ! -f "$root/$f" ]; then
    fail "$f named in the docs does not exist"
  elif "$mrvi" check "$root/$f" >"$tmp/out.txt" 2>"$tmp/err.txt" &&
    grep -q "^$root/$f: valid\$" "$tmp/out.txt"; then
    pass "mrvi check $f"
  else
    fail "mrvi check $f"
    sed 's/^/     /' "$tmp/err.txt" | head -5
  fi
done

# --- relative links ---
# check_links FILE...: prints every broken relative link as FILE: TARGET and
# returns non-zero if there is one.  Links are [text](target); http(s),
# mailto and same-page (#...) links are skipped.
check_links() {
  local file target path bad=0
  for file in "$@"; do
    while IFS= read -r target; do
      case $target in
      http://* | https://* | mailto:* | '#'*) continue ;;
      esac
      path=${target%%#*}
      if [ ! -e "$(dirname "$file")/$path" ]; then
        echo "$file: $target"
        bad=1
      fi
    done < <(grep -oE '\]\([^) ]+\)' "$file" | sed -e 's/^](//' -e 's/)$//')
  done
  return $bad
}

mkdir -p "$tmp/d"
printf 'fine [a](b.md), [self](#x), [web](https://example.org)\n' >"$tmp/d/a.md"
printf 'see [a](a.md#top) and [gone](missing.md#top)\n' >"$tmp/d/b.md"
if check_links "$tmp/d/a.md" "$tmp/d/b.md" >"$tmp/out.txt"; then
  fail "link checker accepts a broken link"
elif [ "$(cat "$tmp/out.txt")" = "$tmp/d/b.md: missing.md#top" ]; then
  pass "link checker reports exactly the broken link"
else
  fail "link checker output: $(cat "$tmp/out.txt")"
fi
nlinks=$(cat "${docs[@]}" | grep -oE '\]\([^) ]+\)' | grep -cvE '\]\((https?:|mailto:|#)')
if check_links "${docs[@]}" >"$tmp/out.txt"; then
  pass "all $nlinks relative links in README.md and doc/*.md resolve"
else
  fail "broken links:"
  sed 's/^/     /' "$tmp/out.txt"
fi

# --- the tutorial prints the shipped file ---
tut=$root/doc/tutorial.md
sed -n '/^## 2\./,/^## 3\./p' "$tut" | sed -n '/^```yaml$/,/^```$/p' | sed '1d;$d' >"$tmp/printed.yaml"
grep -v '^#' "$root/systems/tutorial_spring.yaml" >"$tmp/shipped.yaml"
if [ -s "$tmp/printed.yaml" ] && cmp -s "$tmp/printed.yaml" "$tmp/shipped.yaml"; then
  pass "doc/tutorial.md prints systems/tutorial_spring.yaml"
else
  fail "doc/tutorial.md and systems/tutorial_spring.yaml differ"
  diff "$tmp/printed.yaml" "$tmp/shipped.yaml" | head -10 | sed 's/^/     /'
fi

# --- the docs cite the paper by number, not by LaTeX label ---
# doc/theory.md holds the one table from labels to numbers.
labels='(^|[^A-Za-z])(eq|th|ex|lemma|tab|fig):[A-Za-z]'
if grep -nE "$labels" "$root"/doc/*.md | grep -v "^$root/doc/theory.md:" >"$tmp/labels.txt"; then
  fail "doc/*.md cite LaTeX labels (use the numbers of doc/theory.md's table):"
  sed "s|^$root/||; s/^/     /" "$tmp/labels.txt" | head -10
else
  pass "doc/*.md cite no LaTeX labels outside doc/theory.md's table"
fi

# --- the repository stands alone ---
# The patterns are assembled so that this file does not match itself.
notes="DES""IGN"
outside="\.\./sha""red"
if git -C "$root" rev-parse --git-dir >/dev/null 2>&1; then
  git -C "$root" ls-files -z >"$tmp/files"
else # a source tree without git: everything but build directories
  (cd "$root" && find . -path ./.git -prune -o -type f ! -path '*/meson-*' -print0) >"$tmp/files"
fi
(cd "$root" && xargs -0 grep -IlE "$notes|$outside" <"$tmp/files") >"$tmp/hits.txt" 2>/dev/null
if [ -s "$tmp/hits.txt" ]; then
  fail "files refer to design notes or to the directory outside the repository:"
  sed 's/^/     /' "$tmp/hits.txt"
else
  pass "no file refers to design notes or outside the repository ($(tr -cd '\0' <"$tmp/files" | wc -c) files)"
fi

# --- every source path the docs name exists (the layout moves with them) ---
grep -ohE '(src|constraints|tests|bench)/[A-Za-z0-9_./-]+\.(c|h|sh|py)|src/cli/mrvi-plot|src/[a-z]+/[A-Za-z0-9_./-]*mrvi-plot' \
  "${docs[@]}" | sort -u >"$tmp/paths.txt"
missing=$(grep -v NAME "$tmp/paths.txt" | while read -r f; do [ -e "$root/$f" ] || echo "$f"; done)
npaths=$(grep -c . "$tmp/paths.txt")
if [ -n "$missing" ]; then
  fail "source paths named in README.md or doc/*.md do not exist: $(echo $missing)"
elif [ "$npaths" -lt 20 ]; then
  fail "only $npaths source paths found in the docs (the pattern broke?)"
else
  pass "all $npaths source paths named in README.md and doc/*.md exist"
fi

# --- the gallery has every shipped system, with its figures ---
# (doc/gallery.sh regenerates it; a new system without an entry fails here.)
gallery=$root/doc/gallery.md
absent=""
for f in "$root"/systems/*.yaml; do
  n=$(basename "$f" .yaml)
  if ! grep -q "^## $n\$" "$gallery" ||
    ! grep -q "](gallery/${n}_[a-z]*\.png)" "$gallery"; then
    absent="$absent $n"
  fi
done
if [ -n "$absent" ]; then
  fail "doc/gallery.md lacks (run doc/gallery.sh):$absent"
else
  pass "doc/gallery.md shows every system of systems/"
fi
images=$(grep -oE '\(gallery/[A-Za-z0-9_.-]+\.png\)' "$gallery" | tr -d '()')
gone=$(for i in $images; do [ -s "$root/doc/$i" ] || echo "$i"; done)
if [ -z "$images" ] || [ -n "$gone" ]; then
  fail "doc/gallery.md: missing figures: $(echo $gone)"
else
  pass "doc/gallery.md: its $(echo "$images" | wc -w) figures exist"
fi

# --- links to headings resolve (tests/doc_anchors.py) ---
# The checker first shown to report exactly the broken anchor (a repeated
# heading takes "-1", punctuation is dropped).
# shellcheck disable=SC2016 # backquotes: a Markdown fence, not a command
printf '# A title\n## Goals (issue 8): where?\n## A title\n```\n# not a heading\n```\n' >"$tmp/d/c.md"
printf '[a](#goals-issue-8-where) [b](#a-title-1) [c](#not-a-heading) [d](c.md#a-title)\n' >>"$tmp/d/c.md"
if /usr/bin/python3 "$root/tests/doc_anchors.py" "$tmp/d/c.md" >"$tmp/out.txt"; then
  fail "anchor checker accepts a broken anchor"
elif [ "$(head -1 "$tmp/out.txt")" = "$tmp/d/c.md: #not-a-heading" ] &&
  grep -q "^4 anchors checked, 1 broken$" "$tmp/out.txt"; then
  pass "anchor checker reports exactly the broken anchor"
else
  fail "anchor checker output: $(cat "$tmp/out.txt")"
fi
if /usr/bin/python3 "$root/tests/doc_anchors.py" "${docs[@]}" >"$tmp/out.txt"; then
  pass "README.md and doc/*.md: $(tail -1 "$tmp/out.txt")"
else
  fail "links to headings that do not exist:"
  sed 's/^/     /' "$tmp/out.txt"
fi

# --- bench/plot_performance.py draws doc/performance.md's figures ---
# From the shipped results files, every figure; then, on two synthetic
# bench_floor outputs, perf_idle_ratios.png's rule: the latest run listed
# in idle_runs.txt gives each point, only the blocks named are read, and a
# listed run without a ratio or a missing block is an error.
if /usr/bin/python3 -c "import matplotlib" 2>/dev/null; then
  plotp=$root/bench/plot_performance.py
  if /usr/bin/python3 "$plotp" --data "$tmp/idle.txt" "$root/doc/results" \
    "$tmp/figs" >"$tmp/out.txt" 2>&1; then
    small=""
    for f in perf_fpu_p perf_mristep perf_lattice perf_floor \
      perf_floor_ratios perf_chain perf_idle_ratios; do
      [ "$(head -c 4 "$tmp/figs/$f.png" 2>/dev/null | od -An -tx1 | tr -d ' \n')" = 89504e47 ] &&
        [ "$(stat -c %s "$tmp/figs/$f.png")" -gt 10240 ] || small="$small $f"
    done
    runs=$(grep -cvE '^[[:space:]]*(#|$)' "$root/doc/results/idle_runs.txt")
    used=$(awk '{print $5, $6, $7}' "$tmp/idle.txt" | sort -u | wc -l)
    if [ -n "$small" ]; then
      fail "plot_performance.py: missing or not a PNG:$small"
    elif [ "$used" != "$runs" ] || [ "$(wc -l <"$tmp/idle.txt")" -lt 12 ]; then
      fail "plot_performance.py: $(wc -l <"$tmp/idle.txt") idle points from $used of $runs runs"
    else
      pass "plot_performance.py: 7 figures from doc/results, $(wc -l <"$tmp/idle.txt") idle points from its $runs runs"
    fi
  else
    fail "plot_performance.py on doc/results: $(tail -3 "$tmp/out.txt")"
  fi
  mkdir -p "$tmp/res"
  floor_out() { # NETWORK then lines "n FE ES MM TM"
    printf '## %s\n\n|        n |   FE/RESPA |   ES/RESPA |  MM/Verlet |  TM/Verlet |\n|---:|---:|---:|---:|---:|\n' "$1"
    shift
    for row in "$@"; do
      # shellcheck disable=SC2086
      printf '| %s | %s | %s | %s | %s |\n' $row
    done
    echo
  }
  floor_out lattice2d "1000 1.10 5.00 13.0 -" "10000 1.20 5.50 14.0 -" >"$tmp/res/a.txt"
  {
    echo "=== base"
    floor_out lattice2d "10000 9.99 9.99 - -"
    echo "=== new"
    floor_out lattice2d "10000 0.90 - - -"
    floor_out random3d "1000 - 3.50 - 12.5"
  } >"$tmp/res/b.txt"
  printf '# a comment\n2026-01-01 10:00 a.txt\n\n2026-01-02 11:00 b.txt new  # not base\n' \
    >"$tmp/res/idle_runs.txt"
  cat >"$tmp/want.txt" <<'EOF_'
lattice2d FE/RESPA 1000 1.1 2026-01-01 10:00 a.txt
lattice2d FE/RESPA 10000 0.9 2026-01-02 11:00 b.txt
lattice2d ES/RESPA 1000 5 2026-01-01 10:00 a.txt
lattice2d ES/RESPA 10000 5.5 2026-01-01 10:00 a.txt
lattice2d MM/Verlet 1000 13 2026-01-01 10:00 a.txt
lattice2d MM/Verlet 10000 14 2026-01-01 10:00 a.txt
random3d ES/RESPA 1000 3.5 2026-01-02 11:00 b.txt
random3d TM/Verlet 1000 12.5 2026-01-02 11:00 b.txt
EOF_
  if /usr/bin/python3 "$plotp" --data "$tmp/got.txt" "$tmp/res" "$tmp/rfigs" \
    >"$tmp/out.txt" 2>&1 && cmp -s "$tmp/got.txt" "$tmp/want.txt"; then
    pass "plot_performance.py: each idle point from the latest run listed, only the blocks named"
  else
    fail "plot_performance.py: idle points $(diff "$tmp/want.txt" "$tmp/got.txt" | tr '\n' ' ') $(tail -2 "$tmp/out.txt")"
  fi
  # refused NAME PATTERN: the script exits non-zero with PATTERN in its output
  refused() {
    local rc
    /usr/bin/python3 "$plotp" "$tmp/res" "$tmp/rfigs" >"$tmp/out.txt" 2>&1
    rc=$?
    if [ $rc -ne 0 ] && grep -q "$2" "$tmp/out.txt"; then
      pass "plot_performance.py: $1"
    else
      fail "plot_performance.py: $1 (exit $rc): $(tail -2 "$tmp/out.txt")"
    fi
  }
  printf '2026-01-01 10:00 a.txt\n2026-01-02 11:00 b.txt base\n2026-01-03 12:00 b.txt gone\n' \
    >"$tmp/res/idle_runs.txt"
  refused "a block that is not in its file is an error" "b.txt: no block gone"
  printf '2026-01-01 10:00 a.txt\n2026-01-03 12:00 b.txt base\n' >"$tmp/res/idle_runs.txt"
  floor_out lattice2d "10000 - - - -" >"$tmp/res/b.txt"
  sed -i '1i === base' "$tmp/res/b.txt"
  refused "a listed run without a ratio is an error" \
    "idle_runs.txt:2: 2026-01-03 12:00 b.txt has no ratio"
else
  echo "skipped: plot_performance.py (/usr/bin/python3 lacks matplotlib)"
fi

# --- shown outputs equal what the tool prints (tests/doc_outputs.py) ---
py=/usr/bin/python3
[ -x "$py" ] || py=python3
sed 's/max rel\. energy error  2\.707e-04/max rel. energy error  2.859e-04/' \
  "$root/doc/tutorial.md" >"$tmp/drift.md"
sed 's/wall time              0\.[0-9]* s/wall time              9.999 s/' \
  "$root/doc/tutorial.md" >"$tmp/timing.md"
if cmp -s "$root/doc/tutorial.md" "$tmp/drift.md"; then
  fail "doc/tutorial.md no longer shows the energy error 2.707e-04 the checker's self-test changes"
elif "$py" "$root/tests/doc_outputs.py" "$mrvi" "$root" "$tmp/drift.md" >"$tmp/drift.txt" 2>&1; then
  fail "doc_outputs.py missed a drifted energy error"
else
  pass "doc_outputs.py catches a drifted energy error"
fi
if cmp -s "$root/doc/tutorial.md" "$tmp/timing.md"; then
  fail "the checker's self-test found no wall time in doc/tutorial.md"
elif "$py" "$root/tests/doc_outputs.py" "$mrvi" "$root" "$tmp/timing.md" >"$tmp/timing.txt" 2>&1; then
  pass "doc_outputs.py ignores timings"
else
  fail "doc_outputs.py compared a timing: $(grep FAIL "$tmp/timing.txt")"
fi
if "$py" "$root/tests/doc_outputs.py" "$mrvi" "$root" >"$tmp/outputs.txt" 2>&1; then
  pass "$(tail -1 "$tmp/outputs.txt")"
else
  fail "outputs shown in the docs differ from the tool's:"
  grep -A2 '^FAIL' "$tmp/outputs.txt" | sed 's/^/     /'
fi

test_finish

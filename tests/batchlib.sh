# Helpers of the batch tests (test_batch.sh, test_batch_mpi.sh; sourced
# after testlib.sh).  Without the HDF5 tools the test is skipped.

if ! command -v h5diff >/dev/null || ! command -v h5dump >/dev/null; then
  echo "skipped: needs h5diff and h5dump"
  exit 77
fi

# column FILE NAME: the values of /cases/NAME, one per line.
column() {
  h5dump -y -d "/cases/$2" "$1" 2>/dev/null |
    sed -n '/DATA {/,/}/p' | sed '1d;$d' | tr ',' '\n' |
    sed 's/^ *//;s/ *$//;/^$/d'
}

# same_runs A B: case files of masters A and B equal (h5diff, every dataset
# and attribute) for case numbers given as "a:b" pairs on stdin.
same_runs() {
  local a=$1 b=$2 pair ok=1
  while read -r pair; do
    h5diff "${a%.h5}.cases/case_$(printf %04d "${pair%%:*}").h5" \
      "${b%.h5}.cases/case_$(printf %04d "${pair##*:}").h5" >/dev/null 2>&1 ||
      ok=0
  done
  [ "$ok" = 1 ]
}

# The table columns that do not hold wall-clock times.
same_table() {
  local d
  for d in status steps energy_error stop_reason overrides seed; do
    h5diff "$1" "$2" "/cases/$d" "/cases/$d" >/dev/null 2>&1 || return 1
  done
}

#!/usr/bin/env bash
# README walk: runs every command of README.md's ```sh blocks as written, from the repository root, so the README
# stays true. One-shot commands must exit 0. Not run, each with its reason printed: `make ...` (the set-up that runs
# this test), `export ...` (an environment line), commands that start a long-running process (`... &`, the component
# processes, `record`/`replay` that wait for a running cell). Lines that read ../shared need the dataset: without it
# they are skipped, and with nothing run the test is skipped (exit 77).
#   walk_readme.sh <repository root>
set -u
root=${1:?repository root}
cd "$root" || exit 2
[ -x build/bin/cellcal ] || { echo "walk_readme: build/bin/cellcal not built here"; exit 77; }
created=()
for f in back.csv shift.mcap; do [ -e "$f" ] || created+=("$f"); done
ran=0 failed=0 n=0
while IFS= read -r line; do
  n=$((n + 1))
  cmd=$(sed -E 's/[[:space:]]+#.*$//; s/[[:space:]]+$//' <<<"$line")
  [ -z "$cmd" ] && continue
  why=""
  case "$cmd" in
    make\ *) why="the set-up that runs this test" ;;
    export\ *) why="an environment line" ;;
    *"&") why="starts a long-running process" ;;
    build/bin/cellcal_*) why="a component process: runs until stopped" ;;
    "build/bin/cellcal record "* | "build/bin/cellcal replay "*) why="needs a running cell" ;;
    "build/bin/cellcal foxglove"*) why="serves until stopped (ctest -R Foxglove runs it beside a cell)" ;;
  esac
  if [ -z "$why" ] && grep -q "\.\./shared" <<<"$cmd" && [ ! -d ../shared/datasets ]; then why="../shared/datasets missing"; fi
  if [ -n "$why" ]; then
    echo "walk_readme: not run ($why): $cmd"
    continue
  fi
  echo "walk_readme: run: $cmd"
  start=$(date +%s)
  if timeout 600 bash -c "$cmd" >"/tmp/walk_readme_$$.log" 2>&1; then
    echo "walk_readme:   ok ($(($(date +%s) - start)) s)"
    ran=$((ran + 1))
  else
    code=$?
    echo "walk_readme:   FAILED with exit $code:"
    tail -20 "/tmp/walk_readme_$$.log"
    failed=$((failed + 1))
  fi
done < <(awk '/^```sh/{f=1;next} /^```/{f=0} f' README.md)
rm -f "/tmp/walk_readme_$$.log"
for f in "${created[@]}"; do rm -f "$f"; done
echo "walk_readme: $ran command(s) ran as written, $failed failed"
[ "$failed" -eq 0 ] || exit 1
[ "$ran" -gt 0 ] || exit 77

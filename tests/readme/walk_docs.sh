#!/usr/bin/env bash
# The documentation walk: runs every command of the ```sh blocks of the given Markdown files as written, from the
# repository root, so README and docs stay true. Each file's commands run in order in one shell (a `cd` or a variable
# set by one command holds for the next, as for a reader typing them); a command spans lines while bash says it is
# incomplete (a trailing backslash, a loop, an open parenthesis). A command must exit 0, or the code its first line
# names in a comment (`# exit 3`). Not run, each with its reason printed: `make ...` (the set-up that runs this test),
# `export ...`, commands that start a long-running process (`... &`, the component processes, `record`/`replay`
# that wait for a running cell, `foxglove`), benchmarks (`bench-cell`, `bench-servo`: minutes, `make bench`), commands that need root
# and change this host (`sudo`, files under /etc), a Docker engine or a systemd journal. Commands that read
# ../shared need the dataset: without it the rest of that file is skipped; with nothing run the test is skipped (77).
# A ```output block right after a command quotes what it prints (```output tol=0.05: figures within 5 %; without it,
# within one unit of their last digit): each quoted line must be printed (match_output.awk), so a figure the code no
# longer gives fails the walk. `when=TEXT` at the end of that line: compared only when the command printed TEXT (a
# real-time run whose figures depend on the machine: a busy one loses poses; said as a NOTE when not compared).
#   walk_docs.sh <repository root> FILE.md|FOLDER...   (a folder: its *.md not named before it, in name order)
set -u
root=${1:?repository root}
here=$(cd "$(dirname "$0")" && pwd)
shift
cd "$root" || exit 2
[ -x build/bin/cellcal ] || { echo "walk_docs: build/bin/cellcal not built here"; exit 77; }
created=()
for f in back.csv shift.mcap; do [ -e "$f" ] || created+=("$f"); done
total_ran=0 total_failed=0
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT

why_not() {  # the reason a command is not run, or nothing
  local first=$1
  case "$first" in
    "make demo"* | "make test"*) echo "the set-up that runs this test" ;;
    "make install"*) echo "installs into this system (ctest -R Install checks cmake --install into a scratch prefix)" ;;
    make\ *) echo "a make target of its own (make bench, make fuzz: minutes)" ;;
    export\ *) echo "an environment line" ;;
    *"&") echo "starts a long-running process" ;;
    build/bin/cellcal_* | *" build/bin/cellcal_"*) echo "a component process: runs until stopped" ;;
    "build/bin/cellcal record --out"* | "build/bin/cellcal replay "*) echo "needs a running cell" ;;
    "build/bin/cellcal foxglove"*) echo "serves until stopped (ctest -R Foxglove runs it beside a cell)" ;;
    *bench-cell* | *bench-servo*) echo "a benchmark: minutes of load (make bench)" ;;
    sudo\ * | *" /etc/"*) echo "needs root and changes this host" ;;
    docker\ * | *"docker compose"*) echo "needs a Docker engine" ;;
    journalctl\ *) echo "reads a systemd journal" ;;
  esac
}

# A folder stands for its *.md not named before it.
docs=()
for a in "$@"; do
  if [ -d "$a" ]; then
    for f in "${a%/}"/*.md; do
      [[ " ${docs[*]} " == *" $f "* ]] || docs+=("$f")
    done
  else
    docs+=("$a")
  fi
done
for doc in "${docs[@]}"; do
  script="$work/$(basename "$doc").sh"
  {
    echo "ran=0 failed=0 log=$work/cmd.log work_last=$work/last.log"
    echo "cd '$PWD'"
  } > "$script"
  acc="" no_shared="" last_ran="" expect="" n_expect=0 when=""
  while IFS= read -r line; do
    # A quoted output: ```output [tol=F] after the command whose output it quotes (match_output.awk compares).
    if [[ "$line" == "#<<output"*">>" ]]; then
      n_expect=$((n_expect + 1))
      expect="$work/expect_$(basename "$doc")_$n_expect.txt"
      : > "$expect"
      tol=$(sed -nE 's/.*tol=([0-9.]+).*/\1/p' <<<"$line")
      tol=${tol:-0}
      when=$(sed -nE 's/.*when=(.*)>>$/\1/p' <<<"$line")
      continue
    fi
    if [[ "$line" == "#<<expect>>"* ]]; then printf '%s\n' "${line#\#<<expect>>}" >> "$expect"; continue; fi
    if [ "$line" = "#<<end of output>>" ]; then
      if [ -n "$last_ran" ]; then
        printf 'echo %q\n' "walk_docs: $doc: output of: $last_ran" >> "$script"
        if [ -n "$when" ]; then  # figures of a run that depends on the machine's timing: compared when it was whole
          printf 'if ! grep -qF %q "$work_last"; then echo %q;\n' "$when" \
            "walk_docs:   NOTE: not compared: the run did not print '$when' (a busy machine); its figures differ" >> "$script"
          printf 'el' >> "$script"
        fi
        printf 'if awk -v tol=%s -f %q %q "$work_last"; then echo "walk_docs:   figures as quoted"; ran=$((ran + 1));\n' \
          "$tol" "$here/match_output.awk" "$expect" >> "$script"
        printf 'else echo "walk_docs:   FAILED: the quoted output is stale"; failed=$((failed + 1)); fi\n' >> "$script"
      else
        printf 'echo %q\n' "walk_docs: $doc: output not checked (its command was not run)" >> "$script"
      fi
      continue
    fi
    if [ "$line" = "#<<end of block>>" ]; then acc=""; continue; fi
    acc+="${acc:+$'\n'}$line"
    [[ "$line" == *\\ ]] && continue
    bash -n -c "$acc" 2> /dev/null || continue
    cmd=$acc
    acc=""
    first=$(head -1 <<<"$cmd" | sed -E 's/[[:space:]]+#.*$//; s/[[:space:]]+$//')
    [ -z "$first" ] && [ "$(wc -l <<<"$cmd")" -eq 1 ] && continue
    [[ "$first" == \#* ]] && continue
    want=$(head -1 <<<"$cmd" | sed -nE 's/.*#.*\bexit ([0-9]+)\b.*/\1/p')
    want=${want:-0}
    why=$(why_not "$first")
    if [ -z "$why" ] && grep -q "\.\./shared" <<<"$cmd" && [ ! -d ../shared/datasets ]; then no_shared=yes; fi
    [ -n "$no_shared" ] && [ -z "$why" ] && why="../shared/datasets missing (it and what follows from it)"
    if [ -n "$why" ]; then
      printf 'echo %q\n' "walk_docs: $doc: not run ($why): $first" >> "$script"
      last_ran=""
      continue
    fi
    last_ran=$first
    {
      printf 'echo %q\n' "walk_docs: $doc: run: $first"
      echo 'start=$SECONDS'
      printf '{\n%s\n} > "$log" 2>&1\n' "$cmd"
      echo 'rc=$?'
      echo 'cp "$log" "$work_last"'
      printf 'if [ $rc -eq %s ]; then echo "walk_docs:   ok ($((SECONDS - start)) s)"; ran=$((ran + 1));\n' "$want"
      printf 'else echo "walk_docs:   FAILED: exit $rc (want %s):"; tail -20 "$log"; failed=$((failed + 1)); fi\n' "$want"
    } >> "$script"
  done < <(awk '/^```sh/{f=1;next}
                /^```output/{o=1; t=$0; sub(/^```output */, "", t); print "#<<output " t ">>"; next}
                /^```/{if(f)print "#<<end of block>>"; if(o)print "#<<end of output>>"; f=0; o=0; next}
                f{print} o{print "#<<expect>>" $0}' "$doc")
  echo 'echo "$ran $failed" > '"'$work/result'" >> "$script"
  bash "$script"
  read -r ran failed < "$work/result"
  total_ran=$((total_ran + ran))
  total_failed=$((total_failed + failed))
done
for f in "${created[@]}"; do rm -f "$f"; done
echo "walk_docs: $total_ran command(s) ran as written, $total_failed failed"
[ "$total_failed" -eq 0 ] || exit 1
[ "$total_ran" -gt 0 ] || exit 77

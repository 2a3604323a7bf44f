# Checks an output block a document quotes against what its command printed (tests/readme/walk_docs.sh).
#   awk -v tol=0.05 -f match_output.awk EXPECTED ACTUAL
# Every non-empty line of EXPECTED must be a line of ACTUAL (in any order, whitespace runs alike) whose figures each
# lie within `tol` (relative) of the quoted ones, or within one unit of the quoted figure's last digit (0.3995 matches
# 0.3994..0.3996 with tol=0). Text between the figures must be the same. Exit 1 naming each quoted line not found,
# with the printed line of the same words nearest to it.
function norm(s) {
  gsub(/[ \t]+/, " ", s)
  sub(/^ /, "", s)
  sub(/ $/, "", s)
  return s
}
# Splits s into its words (figures replaced by #) and its figures; returns the number of figures.
function split_figures(s, figs,    n, rest, pre, m) {
  n = 0
  shape = ""
  rest = s
  while (match(rest, /[-+]?[0-9]+(\.[0-9]+)?([eE][-+]?[0-9]+)?/)) {
    pre = substr(rest, 1, RSTART - 1)
    m = substr(rest, RSTART, RLENGTH)
    # A figure glued to a word's letters (v95, q3, joint2) stays part of the word.
    if (RSTART > 1 && substr(rest, RSTART - 1, 1) ~ /[A-Za-z_]/) {
      shape = shape pre m
    } else {
      shape = shape pre "#"
      figs[++n] = m
    }
    rest = substr(rest, RSTART + RLENGTH)
  }
  shape = shape rest
  return n
}
# One unit of the last digit of a figure as written: "0.3995" -> 0.0001, "95" -> 1, "1.5e-3" -> 1e-4.
function last_unit(f,    mant, ex, dot) {
  mant = f
  ex = 0
  if (match(f, /[eE]/)) {
    mant = substr(f, 1, RSTART - 1)
    ex = substr(f, RSTART + 1) + 0
  }
  dot = index(mant, ".")
  return (dot ? 10 ^ (-(length(mant) - dot)) : 1) * 10 ^ ex
}
function close_enough(want, got,    w, g, d) {
  w = want + 0
  g = got + 0
  d = w - g
  if (d < 0) d = -d
  return d <= last_unit(want) * 1.0000001 || d <= tol * (w < 0 ? -w : w)
}
FNR == NR {
  line = norm($0)
  if (line != "") expected[++ne] = line
  next
}
{
  line = norm($0)
  if (line != "") actual[++na] = line
}
END {
  bad = 0
  for (i = 1; i <= ne; ++i) {
    delete want
    nw = split_figures(expected[i], want)
    want_shape = shape
    found = 0
    nearest = ""
    most = -1
    for (j = 1; j <= na && !found; ++j) {
      delete got
      ng = split_figures(actual[j], got)
      if (shape != want_shape || ng != nw) continue
      agree = 0
      for (k = 1; k <= nw; ++k) agree += close_enough(want[k], got[k])
      if (agree == nw) found = 1
      else if (agree > most) {
        most = agree
        nearest = actual[j]
      }
    }
    if (!found) {
      bad = 1
      print "match_output: quoted but not printed (figures within " tol * 100 " %): " expected[i]
      print "match_output:   printed" (nearest == "" ? ": no line of the same words" : ": " nearest)
    }
  }
  exit bad
}

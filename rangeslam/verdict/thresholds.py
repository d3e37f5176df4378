"""Every threshold of the verdicts, named once: what it means and what set it.

The estimators (:mod:`rangeslam.mdu`, :mod:`rangeslam.localization`, :mod:`rangeslam.beacons`)
and the checks of :mod:`rangeslam.verdict.checks` import them from here; none keeps a copy under
another name. The README's "Verdict thresholds" table lists them with the same words.
"""

from __future__ import annotations

__all__ = [
    "CHI2_LEVEL",
    "EXACT_RTOL",
    "JOINT_WALL_CHECKS",
    "JOINT_WALL_RANGES",
    "NOISE_QUANTILE",
    "PRECISION_FRACTION",
    "RANK_RTOL",
    "RELATIVE_RMS",
    "ROBUST_RATIO",
    "SEARCH_BUDGET",
    "TAIL_SCALE_FLOOR",
    "WALL_CONTRADICTED_MISSING",
]

# --- consistent with the noise ---------------------------------------------------------------

#: Significance of every chi-square test of the verdicts: the residual test against a given
#: ``noise_std`` (sum of squares on the redundancy), the F-test that finds 3-D data fitted in
#: ``dim=2``, and the one-degree-of-freedom gap that makes two minima indistinguishable.
CHI2_LEVEL = 0.999
#: Exact data: an RMS range residual at most this fraction of the median range is round-off.
#: ``noise_std=0`` means exact data and is tested against it.
EXACT_RTOL = 1e-8
#: Without a noise level, an RMS residual above this fraction of the scene (the median range)
#: explains nothing.
RELATIVE_RMS = 0.02
#: Without a noise level, an RMS residual above this multiple of the residuals' robust (MAD)
#: scale means a few large residuals dominate the fit: wrong picks the least squares absorbed.
ROBUST_RATIO = 2.0
#: The robust scale of the tail test is at least this fraction of the scene size (3 mm at 3 m),
#: so a residual must exceed about 0.6% of the scene to count as a wrong pick.
TAIL_SCALE_FLOOR = 1e-3
#: Without a known noise level, the precision and flatness tests assume the largest noise the
#: residuals do not rule out at this level (the lower quantile of chi-square on the redundancy).
NOISE_QUANTILE = 0.05

# --- no unexplained outliers -----------------------------------------------------------------

#: (A range is an inlier while its residual is within :func:`rangeslam.verdict.checks.
#: level_sigmas` noise standard deviations, the level's one-range test; a wrong pick stands out
#: beyond :func:`rangeslam.verdict.checks.tail_limit`, the level's Bonferroni bound: no constant
#: of their own.)

# --- identifiable ----------------------------------------------------------------------------

#: Singular values of a scaled Jacobian below this fraction of the largest are zero: the
#: gauge-free Jacobian of the points, and with unknown range offsets (emission times, clock
#: offsets) the offsets and positions cannot then be told apart (NOT_IDENTIFIABLE).
RANK_RTOL = 1e-7
#: The RMS standard deviation the information implies must be at most this fraction of the scene
#: size (12.5 cm at 2.5 m): beyond it the data do not determine the answer usefully.
PRECISION_FRACTION = 0.05
#: (An answer's points may be flat while their refit in one dimension fewer fits as well, the
#: likelihood-ratio test of the nested model at CHI2_LEVEL
#: (:func:`rangeslam.mdu.planarity.flat_fit_check`); the anchors of a mirror, flat receivers and
#: ranges corrected by fitted offsets while their thinnest RMS spread is within :func:`rangeslam.verdict.checks.flat_limit`: the
#: offset off a plane whose second-order change of a range the level's one-range test cannot
#: see; no constant of their own.)

# --- one answer: restarts agree --------------------------------------------------------------

#: Starts (the search's own and random ones) the judge counts at most beside the generators'
#: alternatives: the stopping rule of Boender and Rinnooy Kan
#: (:func:`rangeslam.verdict.judge.search_complete`) ends them after 7 when every start reached
#: one minimum; this budget leaves it one start more. The result says when the budget, not the
#: rule, ended them. The range-aided judge (:class:`rangeslam.rangeaided.rivals.WorkBudget`)
#: also bounds its work by it: its candidates' LM iterations, this many times the answer's.
SEARCH_BUDGET = 8

#: A wall found jointly by several loudspeakers (:mod:`rangeslam.acoustics.shared_walls`) needs
#: this many echoes in all: a wall has three unknowns, so six leave three to check it (as five
#: microphones on one image source leave two, ``label_echoes``'s least ``min_mics``). Chosen on
#: the cut-corner sessions of ``benchmarks/bench_run_sessions.py`` seeds 618299-618306 (the cut
#: wall heard cleanly at 3 + 3 or 4 + 2 microphones); checked on seeds drawn after
#: (benchmarks/README.md, "rangeslam run on simulated sessions"; tests/test_run_sessions.py).
JOINT_WALL_RANGES = 6
#: ... and this many of them from loudspeakers other than the one that hears it most (at least
#: two loudspeakers): with six in all, a loudspeaker heard at four microphones or fewer (any four
#: ranges fix a point) is checked by two echoes of the others or more, one heard at five (a point
#: checked on its own) by one or more; an echo set that a higher-order image of the walls found
#: explains is no wall. 2 missed the cut wall of cut-corner session 967361 (12 microphones, heard
#: cleanly at 5 + 1, seeds drawn after JOINT_WALL_RANGES); 1 found it and added no wall to 16
#: shoebox sessions (benchmarks/README.md, "rangeslam run on simulated sessions").
JOINT_WALL_CHECKS = 1
#: A wall that one loudspeaker alone labelled is contradicted, and left out
#: (:func:`rangeslam.acoustics.joint_room.room_from_loudspeakers`), when the loudspeakers'
#: first-order images in it predict echoes, at microphones whose specular point lies on the
#: wall's face and where those loudspeakers hear their other walls (and the one that labelled it
#: did not label this one), and at least this many of them are absent from the detections (none
#: within the labelling tolerance), more than are present. One absent echo is allowed for: an
#: echo merged with another arrival is not timed cleanly. Chosen on sessions 618299-618306 and
#: 241681 of ``benchmarks/bench_run_sessions.py`` (8 and 12 microphones, both rooms): the 9
#: walls one loudspeaker labelled that were right had 0-2 of 0-8 predicted echoes absent and more
#: present (shoebox 618299: 2 absent of 8), the wrong one (cut-corner 241681, 8 microphones, 237
#: mm off) 2 of 2. Counting only the other loudspeakers' echoes missed the wrong wall of held-out
#: cut-corner 272702 (8 microphones, 205 mm off: 1 of 1 absent); with the labelling
#: loudspeaker's own microphones, 2 of 2, and the right walls above stay (at most 1 absent);
#: checked on seeds drawn after that (benchmarks/README.md, "rangeslam run on simulated
#: sessions"). The same count denies a wall found jointly (:mod:`rangeslam.acoustics.shared_walls`:
#: neither added nor named as unexplained): on cut-corner sessions 762838-762853 and 487130 (8
#: and 12 microphones) the right walls it found had 0-1 predicted echoes absent against 7-11
#: present, the true cut wall named unexplained (5 echoes) 0 against 6-9, a plane through the
#: room (762848, 12 microphones, named unexplained with 5 echoes) 12 absent against 5; checked on
#: seeds drawn after (benchmarks/README.md, same section).
WALL_CONTRADICTED_MISSING = 2

"""Every default of the service, once: the CLI (`zenoh_track.__main__`), the estimation and
tracking classes and the tests read them from here.

Protocol constants (version, namespace, endpoint, statuses, key names) live with the
wire contract, `zenoh_track.wire`.
"""

from __future__ import annotations

import math

# ---------------------------------------------------------------- display
RATE = 30.0  # Hz: display instants n / RATE (docs/protocol.md)
CLOCK = "realtime"  # or "lockstep"
BLEND = 0.0  # s: absorb a correction over this period (0: plain prediction)
BLEND_SPEED = 0.0  # m/s: absorb a correction at this speed (0: no speed limit)
LAG = 0.0  # s: display instants lag the clock, smoothed when bracketed
# s: how often a realtime service looks again who subscribes display/ and tracks/, and
# how often it asks again about the tracks' keys it puts (so that one who left stops costing)
LISTENERS_REFRESH = 0.1
LISTENERS_RESET = 60.0
# rows a realtime pass applies at most when more wait (batched scans put faster than they
# are applied: a pass of each scan, not of all, and the frames due between them)
PASS_ROWS = 16_384
TRACKS_QUEUE = 20_000  # tracks/ messages a realtime service holds for slow subscribers, at most
# the cyclic collector's thresholds while a service runs (Python's: 700, 10, 10): a pass
# of 1,024 single messages made ~3 young collections and, in a flood of 100,000, two full
# ones of ~20 ms (0.7 us a message, docs/performance.md); objects are still
# freed by reference counting, only cycles wait longer
GC_THRESHOLDS = (10_000, 10, 10)

# ---------------------------------------------------------------- filters
FILTER = "imm"  # imm, cv, ca, ekf, vdf
Q_CV = 1.0  # m/s^2: white acceleration per axis, q (estimation.models) (CV, IMM nominal)
Q_CA = 0.5  # m/s^3: white jerk per axis, q (estimation.models) (CA)
# The default IMM (docs/accuracy.md, "The default filter"): a quiet CV mode, a nominal CV
# mode (Q_CV, or --q) and a CA mode, chained quiet <-> nominal <-> CA, and manoeuvre
# modes entered from any of them (docs/accuracy.md, "Manoeuvres")
IMM_QUIET_Q = 0.003  # m/s^2: the quiet mode's white acceleration std per axis
IMM_CA_Q = 0.2  # m/s^3: the CA mode's white jerk std per axis (docs/accuracy.md, "Exact positions")
IMM_SOJOURN = 600.0  # s: mean time in the quiet and in the nominal mode
IMM_MANOEUVRE_SOJOURN = 10.0  # s: mean time in the CA (and any turn) mode
IMM_INITIAL = (0.1, 0.3, 0.6, 0.0)  # a new track: quiet, nominal, CA, manoeuvre modes
# the manoeuvre modes: (kind, white noise std per axis: m/s^2 for cv, m/s^3 for ca; for
# ct also its turn rate, deg/s): coordinated turns at standard rate both ways (3 deg/s,
# the turn every aircraft flies at each change of heading) and a CV mode whose noise
# covers the rest up to 7 g (docs/accuracy.md, "Coordinated turns at standard rate")
IMM_MANOEUVRE = (("ct", 1.0, 3.0), ("ct", 1.0, -3.0), ("cv", 55.0))
# m/s: the most a CV mode's white acceleration changes the velocity over one step (q |dt|,
# one sigma per axis; 0: no bound): 55 m/s^2 for 5 s, so the widest mode is as designed
# up to 5 s and beyond grows no wider than an aircraft can turn (a 7 g turn reverses
# 200 m/s within 9 s): a track after missed scans or under an en-route radar
# (docs/accuracy.md, "Beyond 5 s")
IMM_WIDE_DV = 275.0
IMM_ONSET = 30000.0  # s: 1 / the rate of entering the manoeuvre modes (docs/accuracy.md)
IMM_TURN_SOJOURN = 5.0  # s: mean time in a manoeuvre mode
# s: ... in a manoeuvre mode of kind "ct" (a turn at a known rate; longer holds a turn at
# exactly that rate better and every other rate worse: docs/accuracy.md, "Sticky turns")
IMM_CT_SOJOURN = 5.0
IMM_CT_ENTRY = 1.0  # a "ct" manoeuvre mode is entered this many times as often as the others
# of a manoeuvre mode's exits, the share into the quiet mode (steady flight again; the
# nominal mode takes 0.5 less this; docs/accuracy.md, "Straight legs after a manoeuvre")
IMM_EXIT_QUIET = 0.05
# False: one converted-measurement R for every mode, averaged over the mixture of their
# predictions (a third less CPU a row; A, B and C as with each mode's own, docs/accuracy.md)
IMM_MODE_R = False
IMM_GATE_WIDE = 0.02  # the least prior association gives the IMM's widest mode
# m/s^3: > 0 adds a manoeuvre mode turning at its own state's rate (the 3-D coordinated
# turn, `turn.turn_model`) with this white jerk; 0: none (its gains and its cost, 1.2 x
# the six modes' row: docs/accuracy.md, "a turn-rate filter")
IMM_TURN_ESTIMATED = 0.0
IMM_TURN_CAP = 0.5  # rad/s: a "turn" mode's rate at most (29 deg/s: 7 g at 140 m/s)
IMM_CT_Q = 3.0  # optional turn modes' noise as a multiple of the nominal mode's
IMM_TURN_DEG = 0.0  # deg/s: > 0 adds coordinated-turn modes at +- this (0: none)
VDF_DETECT = 35.0  # VDF manoeuvre detection threshold (fading NIS sum)
VDF_SETTLE = 13.0  # VDF return-to-CV threshold (fading acceleration significance)

# rows per block of the compiled IMM update (estimation/imm_kernel.py): a large pass in
# blocks of IMM_BLOCK, a pass of fewer rows in blocks of IMM_SMALL (less padding); the
# block was chosen by bench/imm_cost.py (not a power of two)
IMM_BLOCK = 40
IMM_SMALL = 8

# ---------------------------------------------------------------- track life
INIT_SPEED = 1000.0  # m/s: prior std of the velocity at initiation
INIT_ACCEL = 10.0  # m/s^2: prior std of the acceleration at initiation (order-3 states)
COAST_AFTER = 2.5  # coasting once the age exceeds this many of the track's scan intervals
DELETE_AFTER = 30.0  # s of simulation time without a measurement

# ---------------------------------------------------------------- unlabelled scans (plots/)
ASSOCIATOR = "gnn"  # gnn or jpda
GATE_PROBABILITY = 0.999  # chi-square gate: a true detection falls outside it 1 in 1,000
PD = 0.9  # detection probability of a sensor
CLUTTER_DENSITY = None  # false detections per m^2 (2-D) or m^3 (3-D); None: estimated
# a confirmed track whose detection beats a miss by less than this log-likelihood ratio
# keeps its miss branch one scan (tracking.second_look; docs/accuracy.md); 0: never
SECOND_LOOK = 4.0  # ln 55 (docs/accuracy.md, "A doubtful update beyond reach waits")
JPDA_MAX_EVENTS = 5000  # joint events enumerated per cluster; more: cheap JPDA
# an aircraft's reach (tracking.reach): the fastest target, m/s (a new track's velocity
# prior has std MAX_SPEED / 3 per axis), its hardest manoeuvre, m/s^2 (10 g), and the
# sigmas of the positions compared added to either
MAX_SPEED = 340.0
MAX_ACCEL = 98.0
REACH_SIGMAS = 3.0
CONFIRM_M, CONFIRM_N = 3, 5  # confirmed once detected in 3 of its last 5 scans ...
CONFIRM_SCORE = 4.6  # ... with a track score (log-likelihood ratio) of at least ln 100
DELETE_MISSES = 6  # a confirmed track is deleted after this many consecutive misses at Pd 0.9
# (at another Pd: as many as are as unlikely, sum -ln(1 - Pd) >= 6 ln 10; tracking.life)
# a detection takes back ln(Pd / DELETE_FALSE_HIT) of that evidence, not all of it: a
# CUSUM of the detections, a false track taking a detection at a scan that often
DELETE_FALSE_HIT = 0.1
DELETE_SIGMA = 2000.0  # m: ... or when its position sigma exceeds this
REORDER = 0.5  # s of simulation time a scan waits for older scans of other sensors

# ---------------------------------------------------------------- sensor noise
# used when a measurement gives none (docs/protocol.md: the service's configured defaults)
SR = 10.0  # m: range
SAZ = math.radians(0.5)  # rad: azimuth
SEL = math.radians(0.5)  # rad: elevation
SIGMA = 1.0  # m: each Cartesian axis
NOISE = (SR, SAZ, SEL, SIGMA)

# ---------------------------------------------------------------- stated noise checked
# (tracking.noise_check, docs/protocol.md §4.3): a sensor whose positions jitter by more
# than RATIO x its stated sigma + FLOOR is reported (and its measurements used with the
# sigma measured); one stating more than RATIO x the measured + FLOOR with a NIS below
# NIS_LOW is reported too
NOISE_WINDOW = 300  # position residuals (one per axis) and NIS values kept per sensor
NOISE_MIN_COUNT = 30  # residuals before a sensor is judged
NOISE_RATIO = 3.0
NOISE_FLOOR = 1.0  # m
NOISE_NIS_LOW = 0.3
NOISE_EVERY = 10.0  # s of wall time: at most one errors/<sensor> report per sensor
# (estimation.timing, docs/timing.md) a time error is heavy-tailed (repeats, late
# packets): a Student t with 3 degrees of freedom of variance sigma_t^2, taken as the
# three-Gaussian scale mixture of that variance closest to it in Kullback-Leibler
# divergence (the fit is tests/test_timing.py's; two Gaussians are 7 x as far from it and
# left the display 1-2 % worse: bench/timing.py), (probability, variance / sigma_t^2) per
# component: 70 % of positions at 0.53 sigma_t, 28 % at 1.3 sigma_t, 1 in 75 at 5 sigma_t
TIME_MIXTURE = ((0.70309, 0.28582), (0.28349, 1.64745), (0.01342, 24.749))

# ---------------------------------------------------------------- time faults
# (docs/protocol.md §6.1) the input limits themselves are protocol constants
# (zenoh_track.wire.keys: MAX_TIME, sizes, bounds)
MAX_JUMP = 600.0  # s: an input farther than this from the picture's time is rejected ...
NEW_TIMELINE = 10  # ... unless this many such inputs come in a row: a new timeline

# ---------------------------------------------------------------- state file (--state)
STATE_PERIOD = 1.0  # s: a checkpoint of the track table this often (and at SIGTERM/SIGINT)

# ---------------------------------------------------------------- the machine's cores
KERNEL_THREADS = 0  # threads of the compiled IMM update over row blocks (0: every core)
PARALLEL_ROWS = 512  # rows of a pass below which one thread does it all (its hand-over
# costs tens of microseconds; 512 rows of the six-mode IMM about 2 ms)

"""Upper bounds of the counts a user asks for (measurements, candidates, runs, samples).

A count above these is a typo or an absurd request (``--poses 1e9`` would exhaust memory long
before it finished), refused up front with the option named. Plain integers, no imports: the
command line's option definitions use them at start-up.
"""

#: measurements or candidate poses of one simulation, plan or calibration
MAX_MEASUREMENTS = 1_000_000
#: Monte-Carlo runs per value, random comparison sets
MAX_RUNS = 1_000_000
#: samples along a trajectory
MAX_SAMPLES = 10_000_000

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

# -- machine files (refused up front, naming the file and the key) ----------------------------

#: bytes of a machine file; a real one is a few kB (a calibrated one with its metadata 2 kB):
#: anything larger is the wrong file, refused before it is read (and read in well under 1 s)
MAX_MACHINE_FILE_BYTES = 1024 * 1024
#: nesting depth of a machine file's YAML (the deepest real key is about 6 levels down)
MAX_YAML_DEPTH = 64
#: values (YAML nodes) of a machine file with its aliases expanded; a real file has a few
#: hundred (a calibrated one about 160): nested aliases ("billion laughs") stop here, and a
#: flat file this big is still composed in well under a second
MAX_YAML_NODES = 20_000
#: a length in a machine file may be at most this many times the machine's own size ...
MAX_LENGTH_RATIO = 1e4
#: ... and never more than this, m (1000 km: no machine is larger; the squares of such lengths
#: still have full precision)
MAX_LENGTH = 1e6
#: largest angle in a machine file, rad (10 turns: rail azimuths, leg angles and offsets are
#: written within a turn or two)
MAX_ANGLE = 20 * 3.141592653589793
#: smallest leg travel per reading unit of a Stewart leg, m (a femtometre per count: no encoder
#: is finer; a smaller gain makes the readings of a real leg overflow)
MIN_GAIN = 1e-15

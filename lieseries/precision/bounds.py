"""The bounds every check and conversion of the package shares: digits, bits, orders, times, samples, magnitudes."""

#: Fewest decimal digits an mpmath computation (Lie series, references) accepts: below double's 15 digits an
#: mpmath run has nothing to offer over heyoka in double.
MIN_DPS = 15
#: Most decimal digits an mpmath computation accepts (about 33,000 bits).
MAX_DPS = 10_000
#: Most bits heyoka's arbitrary precision is used with: its Taylor order grows like 0.35 bits, and compiling an
#: order-350 integrator of the rigid body already takes seconds (docs/api.md, "Limits").
MAX_BITS = 1024
#: Highest series order the Lie engine computes (the cost grows like order^2 per node of the field).
MAX_ORDER = 2000
#: Times lie within 1e-MAX_TIME_MAGNITUDE .. 1eMAX_TIME_MAGNITUDE in magnitude: runs report the times they reached,
#: and reports plot them, as doubles.
MAX_TIME_MAGNITUDE = 300
#: Most output samples (times) a run or a study keeps.
MAX_SAMPLES = 100_000
#: Largest decimal exponent of an input number (|x| < 10**MAX_EXPONENT, nonzero |x| > 10**-MAX_EXPONENT).
MAX_EXPONENT = 4000
#: Most digits of a number written as a decimal string (a run uses at most MAX_DPS of them).
MAX_DIGITS = 2 * MAX_DPS

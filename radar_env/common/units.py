"""Unit constants. Everything inside the package is SI; convert at the edges with these."""

import math

G0_M_S2 = 9.80665
"""Standard gravity (m/s^2). Bizup uses 9.8 and Adrian 9.81; the 0.1% difference is below every tolerance here."""
KNOT_M_S = 1852.0 / 3600.0
NM_M = 1852.0
FT_M = 0.3048
DEG = math.pi / 180.0

"""Normal gravity: WGS84 Somigliana formula with the standard free-air height correction."""

import math

STANDARD_GRAVITY = 9.80665  # m/s^2, the conventional value (CGPM 1901)

# WGS84 constants (NIMA TR8350.2, eq. 4-1 and 4-3)
_GE = 9.7803253359       # normal gravity at the equator, m/s^2
_K = 0.00193185265241    # Somigliana's constant
_E2 = 0.00669437999013   # first eccentricity squared
_A = 6378137.0           # semi-major axis, m
_F = 1.0 / 298.257223563
_M = 0.00344978650684    # omega^2 a^2 b / GM


def normal_gravity(latitude_deg, altitude_m=0.0):
    """Return WGS84 normal gravity (m/s^2) at a geodetic latitude (deg) and height (m).

    Somigliana's closed formula on the ellipsoid, then the second-order height correction
    of NIMA TR8350.2 eq. 4-3. Raises ValueError for a latitude outside [-90, 90].
    """
    if not -90.0 <= latitude_deg <= 90.0:
        raise ValueError(f'latitude {latitude_deg} deg is outside [-90, 90]; pass degrees')
    s2 = math.sin(math.radians(latitude_deg)) ** 2
    g0 = _GE * (1.0 + _K * s2) / math.sqrt(1.0 - _E2 * s2)
    h = float(altitude_m)
    return g0 * (1.0 - 2.0 / _A * (1.0 + _F + _M - 2.0 * _F * s2) * h + 3.0 / _A ** 2 * h * h)


def resolve_gravity(gravity=None, latitude=None, altitude=0.0):
    """Pick the gravity magnitude and say where it came from: explicit, latitude, or standard."""
    if gravity is not None:
        if not 9.7 <= gravity <= 9.9:
            raise ValueError(f'gravity {gravity} m/s^2 is not a terrestrial value (9.7..9.9); '
                             'pass m/s^2, not g')
        return float(gravity), 'given'
    if latitude is not None:
        return (normal_gravity(latitude, altitude),
                f'WGS84 normal gravity at {latitude} deg, {altitude} m')
    return STANDARD_GRAVITY, 'standard gravity 9.80665 m/s^2'

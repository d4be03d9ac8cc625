"""Physical and system constants (IS-GPS-200, BDS-SIS-ICD)."""

C = 299792458.0  # speed of light, m/s
MU_GPS = 3.9860050e14  # m^3/s^2
MU_BDS = 3.986004418e14
OMEGA_E_GPS = 7.2921151467e-5  # rad/s
OMEGA_E_BDS = 7.292115e-5
F_REL = -4.442807633e-10  # relativistic clock constant, s/sqrt(m)

FREQ_GPS_L1 = 1575.42e6
FREQ_BDS_B1I = 1561.098e6
WAVELENGTH = {"G": C / FREQ_GPS_L1, "C": C / FREQ_BDS_B1I}

SYSTEM_NAMES = {"G": "GPS", "C": "BDS", "R": "GLO", "E": "GAL", "J": "QZS", "S": "SBS", "I": "IRN"}
SUPPORTED_SYSTEMS = ("G", "C")


def is_bds_geo(sat: str) -> bool:
    """BeiDou GEO satellites (C01-C05, C59-C63) use a different orbit model (BDS ICD 5.2.4.12)."""
    if not sat.startswith("C"):
        return False
    prn = int(sat[1:])
    return prn <= 5 or prn >= 59

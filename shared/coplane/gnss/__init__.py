"""GNSS measurement models: ephemeris, atmosphere, weighting, DGNSS, SPP and Doppler velocity."""

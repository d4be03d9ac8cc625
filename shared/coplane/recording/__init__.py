"""Fleet recordings: fleet.toml, RINEX observation/navigation files, uwb.csv and truth CSVs."""

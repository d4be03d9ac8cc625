"""Accuracy against truth (ENU at the truth point), tables, plots and solution files."""

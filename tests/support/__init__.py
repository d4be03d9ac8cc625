"""Fixtures, synthetic fleets and RTKLIB references shared by the tests (not tests themselves)."""

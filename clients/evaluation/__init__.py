"""Evaluation, `track-eval`: the reference scenarios through a real service, scored
against their truth (RMSE, the bound, NEES, GOSPA, the held-out measure, manoeuvres)."""

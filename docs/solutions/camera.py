"""Reference solution, exercise 3 (field of view): 60 degrees (then try 45)."""
HFOV_DEG = 60.0

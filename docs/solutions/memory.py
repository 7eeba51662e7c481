"""Reference solution, exercise 4 (memory): any of 1, 5, 10 is a valid answer; run all three."""
SEQ_LEN = 10

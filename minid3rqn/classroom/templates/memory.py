"""Exercise 4: memory. This file is the one place to change.

D3RQN learns from windows of SEQ_LEN consecutive steps replayed from a zero LSTM state
(the paper: 5). With 1 the LSTM never sees a history during training, so it cannot
learn to use one; with 10 it learns from longer histories, but each update costs
twice as much.

Your task: run 1, 5 and 10, one after the other, and compare.

    python -m minid3rqn check memory
    python -m minid3rqn exercise memory      (after each edit of SEQ_LEN)

SEQ_LEN must be a whole number from 1 to 50 (a flight lasts at most 50 steps).
"""
SEQ_LEN = 5

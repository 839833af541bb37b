"""The time loop, which knows no family: :func:`~rothe.stepping.evolve.evolve` (step, adapt,
record, checkpoint), the generic step controllers (:mod:`.controllers`), result codes
(:mod:`.results`), progress (:mod:`.progress`) and SIGINT / SIGTERM (:mod:`.interrupt`).
"""

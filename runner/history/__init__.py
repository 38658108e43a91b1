"""A history of every night: each run's figures kept per host, cell spec and thread, and each new night judged against them.

- `environment`: the facts of a night's machine a change point is annotated with (kernel, its command
  line, PREEMPT_RT, CPU model, governors, isolated CPUs, IRQ placement, runner version, scenario hash);
- `night`: a results document as the rows a history keeps of it (pure);
- `store`: those rows in SQLite (one file, the default) or PostgreSQL (a URL), versioned, safe for two
  writers at once (the I/O);
- `judge`: a night against its figures' past nights (pure; change points by a library of the `history` extra);
- `trend`: `runner history`'s report of the nights.

Nothing here is imported by a run or a command that is not given --history (sqlite3 is not loaded by
`runner validate`), and the pure parts do no I/O.
"""

"""The live layer (DESIGN.md §9 "Live session"): a live source's frames solved as they arrive, with
the threads, worker processes and clock that takes; the math is retarget/'s (the prepared solver,
the same for a file take and a stream). No bpy.

- `solver.py`: `LiveSolver`, the receiver-to-solver entry: one frame pushed, one pose solved from
  the frames so far (retarget.solver.PreparedSolver with the causal stance).
- `session.py`: `LiveSession`, a live source with its followers and recorder, pumped by whoever
  runs the loop (`bodycal live`, Blender's timer, a headless station); its solving thread hands the
  frames over, so the thread that pumps never solves.
- `followers.py`: `Follower` (solved on that thread) and `WorkerFollower` (in a worker process),
  latest wins, each frame skipped counted.
- `worker.py`: `SolverProcess`, a follower's LiveSolver in a process of its own.
- `pump_clock.py`: `PumpClock`, when the pump should look for the next frame (locked onto the
  stream's beat).

Nothing here is imported at package import time: the worker process imports `worker.py` alone
(numpy and the solver, no python-osc), the session imports the recorder (python-osc).
"""

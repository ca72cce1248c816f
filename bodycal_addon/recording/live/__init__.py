"""Live sources of tracker frames (DESIGN.md "Live source"; FORMATS.md §6).

- `source.py`: what every live source hands out (`LiveFrame`, `SourceStats`), the `LiveSource`
  protocol and the latest-wins slot. No third-party import: a source for Blender's own XR session
  or OpenVR implements it without the VMC code.
- `vmc.py`: the VMC protocol (OSC over UDP) read and written with python-osc: addresses, the
  parser that turns datagrams into frames, the message builders, Unity's axes.
- `receiver.py`: `VmcReceiver`, a UDP receiver on its own thread.
- `recorder.py`: `LiveRecorder`, every frame of a source into a Recording (FORMATS.md §2).
- `wizard.py`: `LiveWizard`, the calibration steps run with a performer while the recorder records:
  the steps the devices allow, their instructions, auto-completion; `progress.py`: how far a step
  is, measured on the frames since it began against what the offline fit needs.
- `sender.py`: `VmcSender` and `replay`, a Recording sent as a VMC stream in real time.
- `buffer.py`: `LiveRecording`, an append-only Recording a stream fills for the live solve
  (live/solver.py); numpy only.

Nothing else in the engine imports this package at import time (python-osc is imported at the top
of the VMC modules) but the live session (live/session.py) and its Blender glue
(blender/live.py, loaded with the Live panel): the command line's `record`, `stream` and `live` load
it when they run.
"""

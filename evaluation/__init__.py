"""An outside tool's view of BodyCal: tracker recordings made from real motion capture.

Every recording the engine's own tests used to see came from `bodycal_dev/synthetic.py`, whose
performer always faces -Y and wears its trackers the way the engine assumes. This package is
deliberately written as another tool would write it, sharing no code with the engine (it does not
import `bodycal_addon` at all): its own BVH reader, its own rotation helpers, its own anatomy and
its own FORMATS.md writer. It turns a real clip (CMU BVH) into a FORMATS.md recording of a person
wearing an HMD, controllers and trackers strapped at random angles and offsets, standing anywhere
in the play area and facing any way, with the calibration motions performed by the clip's own
skeleton; the BVH joints are the truth.

- `bvh`: read a BVH file, forward kinematics, resampling.
- `performer`: the clip's skeleton as a body (joint centres, hinge axes, calibration poses).
- `session`: the calibration steps then the clip, placed in the play area.
- `touching`: a six-device user's controller pivots and touches on the skin (with a person's
  imprecision), the touching arm placed by inverse kinematics on the clip's bones.
- `capture`: devices strapped on the body, noise and dropouts, the recording file and its truth.
- `level`: a clip's sloped floor laid level, one rigid turn of a take's devices and truth alike.

Not part of the extension (excluded from the zip); used by tests and `benchmarks/bench_real_motion.py`.
"""

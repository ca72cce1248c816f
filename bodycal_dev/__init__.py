"""Development tools beside the engine, excluded from the extension zip: the synthetic performer
(`synthetic`), hand-built bodies and avatar poses for the retargeting tests (`retarget_fixtures`)
and a C3D writer (`c3d_writer`). Tests, benchmarks and `sample_rigs/make_demo_recording.py` import
them from here; the engine never does."""

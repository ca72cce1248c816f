"""Development tools beside the engine, excluded from the extension zip: the synthetic performer
(`synthetic`), hand-built bodies and avatar poses for the retargeting tests (`retarget_fixtures`)
a C3D writer (`c3d_writer`), and `make_demo_recording`, which writes the sample recording the
extension ships. Tests and benchmarks import them from here; the engine and everything else the
extension ships (`sample_rigs` included) never do: this package may import `sample_rigs`, not the
other way."""

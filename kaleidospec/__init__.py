"""kaleidospec: simulate and reconstruct a kaleidoscopic multisampling CASSI.

The work is done by :mod:`sim` (the Mitsuba 3 simulator), :mod:`scenes` (built-in hyperspectral
targets) and :mod:`recon` (reconstruction, which never sees the simulator).  This package is
the application that joins them, one module per stage of the workflow, in the order data
flows:

- :mod:`kaleidospec.instrument` — a design's raw frames and calibration captures (the only
  module here that imports :mod:`sim`);
- :mod:`kaleidospec.calibrate` — captures → one calibration file, cached by design hash;
- :mod:`kaleidospec.reconstruct` — a frame and a calibration → cubes per view count;
- :mod:`kaleidospec.evaluate` — cubes and their truth → scores and the targets;
- :mod:`kaleidospec.report` — summary lines, metrics files, tables, plots, videos;

with :mod:`kaleidospec.models` (the calibrated forward models, their gains and grids) shared
by the stages, and :mod:`kaleidospec.run`, :mod:`kaleidospec.video` and
:mod:`kaleidospec.sweep` wiring the stages for one scene, a sequence and a design sweep.  The
command line (:mod:`kaleidospec.cli`, :mod:`kaleidospec.commands`) wraps those.
"""

__version__ = "0.1.0"

"""The physically based simulator of the kaleidoscopic multisampling CASSI.

``sim`` turns a scene cube and a :class:`sim.optics.design.Design` into raw sensor frames and
calibration captures.  Its rooms follow the light: the optics from the diffuser to the sensor
(:mod:`sim.optics`: the design, glass, the Mitsuba elements, the scene and its tracer), the
transport that integrates the traced optics over every pixel (:mod:`sim.transport.exact`), the bands
(:mod:`sim.bands`) and the sensor (:mod:`sim.sensor`), and what is made of them: raw frames
(:mod:`sim.frame`), design measurements (:mod:`sim.measure`) and calibration captures
(:mod:`sim.captures`).  Importing this package imports nothing heavy; Mitsuba is loaded only by
the modules that render.
"""

"""The physically based simulator of the kaleidoscopic multisampling CASSI.

``sim`` turns a scene cube and a :class:`sim.optics.design.Design` into raw sensor frames and calibration
captures. Modules follow the optical path: the design description (:mod:`sim.optics.design`), glass
dispersion (:mod:`sim.optics.glass`), the optics rendered with Mitsuba 3, and the sensor
(:mod:`sim.sensor`). Importing this package imports nothing heavy; Mitsuba is loaded only by the
modules that render.
"""

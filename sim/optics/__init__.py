"""The optics: what the light meets from the diffuser to the sensor, and how Mitsuba 3 traces it.

The design description (:mod:`~sim.optics.design`) and glass dispersion
(:mod:`~sim.optics.glass`) are plain Python; the elements in the order light meets them
(:mod:`~sim.optics.diffuser`, :mod:`~sim.optics.kaleidoscope`, :mod:`~sim.optics.lens`,
:mod:`~sim.optics.mask`, :mod:`~sim.optics.prism`, :mod:`~sim.optics.camera`, with
:mod:`~sim.optics.dielectric` the glass they are made of) are Mitsuba plugins assembled by
:mod:`~sim.optics.scene`; :mod:`~sim.optics.rays` traces rays through it and
:mod:`~sim.optics.render` renders a cube directly.  :mod:`~sim.optics.variant` picks the Mitsuba
variant.  Importing this package imports nothing heavy.
"""

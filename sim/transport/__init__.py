"""Light transport: where each cube voxel's light lands on the sensor, integrated exactly.

The optics are traced once into smooth maps (:mod:`~sim.transport.maps`); the pixel and view
integrals (:mod:`~sim.transport.pixel_integral`, :mod:`~sim.transport.view_integral`) integrate
them exactly over every pixel; :mod:`~sim.transport.exact` holds the cached transport built from
them, :mod:`~sim.transport.sampled` the Monte Carlo one it is checked against, and
:mod:`~sim.transport.oracle` the exact operator the reconstructions are compared with.
"""

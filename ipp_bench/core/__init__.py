"""The core: the IPP problem in numpy and scipy only (no gymnasium, torch or MuJoCo).

Layers, each importing only those below it (checked by the import-linter contracts in
``pyproject.toml``)::

    twin | team          a mission flown by the digital twin's legs; several UAVs on one belief
    mission              world + belief + sensor + budget clock: fly a leg, what it measured
    gp_fit               the GP prior fitted to a task's field family
    limits               the sizes a task may have, checked before the work
    gains | roadmap      predicted trace reductions; the 3D probabilistic roadmap
    belief_window        the windowed belief of large maps
    belief               GP prior and the Kalman measurement update
    sensor | fields      altitude -> footprint, noise, H; seeded ground-truth fields
    config | data | metrics | legs | _threads
"""

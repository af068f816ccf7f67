"""The thin graph nodes: ``plant``, ``wheels``, ``disturbance``, ``guidance``, ``controller`` and the recorder.

Each holds a core step object, turns messages into arrays
(:mod:`attitude_sil.ros.convert`), calls it and publishes the result; each has
a ``main()`` and a console script (``plant_node``, ...). No physics here.
"""

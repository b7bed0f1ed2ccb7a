"""What the tests share, one module per concept; fixtures live in ``tests/conftest.py``.

``paths`` (the repository and test data), ``names`` (dotted names resolved in the tree),
``wait`` (the one poller, the upper bound on waits, stopping a process), ``clock`` (a clock
the test sets by hand), ``watch`` (what a test hears from another thread or on a key, with
waits on predicates), ``network`` (key prefixes, the hub's shape, peer sessions), then one
module per role or part under test: ``agents``, ``clients``, ``client_fleet``, ``databank``,
``ecl``, ``nested`` (segments measured by another kinematics), ``protocol``, ``ros2``,
``ros2_peer`` (zenoh-ros2-sdk's peer, ``sdk_peer.py``, as a process), ``system``, ``view``,
``hostile`` (bodies a forged answer could carry), ``soak``, ``byor`` (third-party robots)
and ``sweep`` (every URDF of three public collections brought; ``make sweep`` runs it).
"""

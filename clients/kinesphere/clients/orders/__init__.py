"""The orders wing: ``send``, ``play``, ``estop`` and ``lease``, which wait for the robots' acks."""

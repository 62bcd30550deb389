"""Known reference systems and measuring rigs shared by the benchmarks (``bench/``) and the tests.

* :mod:`harness.beam` -- the finite-element cantilever beam of chapter 4 (section 4.4);
* :mod:`harness.rotor` -- the imbalanced-rotor run of chapter 5 (section 5.4) and its noise-free truth;
* :mod:`harness.fault_effect` -- a simulated fault's effect on the target against its fault-free twin;
* :mod:`harness.peers` -- peer identification methods (N4SID, pykoop) behind one predictor interface;
* :mod:`harness.live` -- the live load generator over Zenoh and its latency measurement.

Uses the product's public API only; never imports ``bench``.
"""

"""Looking at a recording or a model: the Rerun views (``rerun_view``, ``live_view`` on
``view_data``), the polar and Bode PNGs (``phase_plots``), and the engineer's figures
(``context_plots``: figures 3.4-3.6; ``prediction_plots``: a planned run's prediction and
figure A.5)."""

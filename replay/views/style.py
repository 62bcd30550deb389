"""Text sizes and widths of the engineer's figures, readable where they are shown.

The report embeds PNGs at 90 dpi on a page about 1080 px wide (``replay.report.document``):
a figure at most ``WIDTH`` in wide (1035 px, some slack for a label past its edge) is shown
at its own size, so its smallest text, ``SMALL`` pt, shows at 9 x 90 / 72 = 11.25 px.

>>> SMALL * 90 / 72 >= 11 and WIDTH * 90 <= 1080
True
"""

SMALL = 9.0  # tick labels, legends, annotations, pt
LABEL = 10.0  # axis labels and panel titles, pt
WIDTH = 11.5  # the widest figure, in

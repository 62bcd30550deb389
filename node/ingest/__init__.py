"""A test cell's own recording as a contract recording: ``ordervib import``.

An ASAM MDF4 file (``asammdf``), an NI TDMS file (``npTDMS``) or a CSV export is read as
the import map says (``mapping``: which source channel is which contract channel, in which
unit, on which clock), each channel converted to the contract's unit (``units``), resampled
to the 40 Hz grid of the sensor clock (``resample``: linear, the phases along the shorter
arc) and written as a recording in the contract's MCAP layout (``write``). ``sources``
reads the three formats (the libraries imported only when a file of theirs is read);
``importer.import_file`` is the one entry.
"""

from node.ingest.importer import ImportReport, import_file, read_map_and_source
from node.ingest.mapping import ChannelMap, ImportMap, TimeSpec, load_map

__all__ = ["ChannelMap", "ImportMap", "ImportReport", "TimeSpec", "import_file", "load_map",
           "read_map_and_source"]

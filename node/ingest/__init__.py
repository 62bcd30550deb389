"""A test cell's own recording as a contract recording: ``ordervib import``.

An ASAM MDF4 file (``asammdf``), an NI TDMS file (``npTDMS``) or a CSV export is read as
the import map says (``mapping``: which source channel is which contract channel, in which
unit, on which clock), each channel converted to the contract's unit (``units``), resampled
to the 40 Hz grid of the sensor clock (``resample``: linear, the phases along the shorter
arc) and written as a recording in the contract's MCAP layout (``write``). ``sources``
reads the three formats (the libraries imported only when a file of theirs is read; ``blanks``
what a CSV column's blank cells mean, ``mdf4_blocks`` whether an MDF4 file is cut);
``coverage`` finds a cut file or a short channel (an error, or a counted gap with
``allow_partial``); ``importer.import_file`` is the one entry, ``summary`` the lines the
command prints.
"""

from node.ingest.coverage import ChannelReport
from node.ingest.importer import METADATA_NAME, ImportReport, import_file, read_map_and_source
from node.ingest.mapping import ChannelMap, ImportMap, TimeSpec, load_map
from node.ingest.summary import summary_lines

__all__ = ["METADATA_NAME", "ChannelMap", "ChannelReport", "ImportMap", "ImportReport", "TimeSpec",
           "import_file", "load_map", "read_map_and_source", "summary_lines"]

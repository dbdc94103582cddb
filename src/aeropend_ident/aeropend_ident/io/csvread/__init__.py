"""Streaming CSV reading of :mod:`aeropend_ident.io.csv_import`: byte blocks cut at line ends
(:mod:`.source`), the row checks with file/line/column messages (:mod:`.table`) and each block's
numbers by pyarrow's CSV parser, or row by row where a block needs the exact messages
(:mod:`.blocks`)."""

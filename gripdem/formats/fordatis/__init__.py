"""The authors' Fordatis archives: one archive file read as written (:mod:`.files`) and
imported into gripdem's conventions (:mod:`.importer`)."""

from gripdem.formats.fordatis.importer import DEFAULT_DIAMETER, ImportReport, read_fordatis

__all__ = ["DEFAULT_DIAMETER", "ImportReport", "read_fordatis"]

"""The fitted head's home: its type (:mod:`.fitted`), the one ``params.json`` schema (:mod:`.params`), the
description of every output folder (:mod:`.folders`, light: the command line's help reads it) and the
skinned glTF writer (:mod:`.skinned`). Import the submodules; this package imports nothing."""

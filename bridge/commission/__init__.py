"""Commissioning from the command line (``python -m bridge config``): any object of a node
over SDO by name or index (:mod:`.access`), CiA 306 DCF dump and load (:mod:`.dcf`), the
command (:mod:`.command`, NAME/HELP/add_arguments/run). docs/config_command.md."""

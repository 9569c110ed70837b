"""``python -m controller``: the ``cheope`` command."""

from controller.cli_entry import main

raise SystemExit(main())

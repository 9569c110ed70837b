"""``python -m controller``: the ``cheope`` command."""

from controller.cli import main

raise SystemExit(main())

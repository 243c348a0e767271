import sys

try:
    from .cli import main
except KeyboardInterrupt:  # Ctrl-C while the libraries load: stop quietly, as later
    sys.exit(130)

sys.exit(main())

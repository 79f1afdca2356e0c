from streamkey.cli import main

raise SystemExit(main())

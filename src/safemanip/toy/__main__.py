from safemanip.toy.oracle import main

raise SystemExit(main())

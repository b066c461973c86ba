from tvf.cli import main

main()

from espdock.cli import main

main()

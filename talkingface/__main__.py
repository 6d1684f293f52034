from talkingface.cli.main import entry

entry()

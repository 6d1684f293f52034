from talkingface.cli import entry

entry()

from lhf_hf.cli.entry import run

run()

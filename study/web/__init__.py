"""The perception study as a static web page (jsPsych 8) and the files it is built from."""

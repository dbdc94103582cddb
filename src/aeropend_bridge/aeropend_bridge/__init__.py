"""Serial bridge to the Arduino Mega acquisition firmware; publishes the same topics as the simulated plant."""

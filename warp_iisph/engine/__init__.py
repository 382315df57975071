"""How kernels meet the machine: device names, CPU thread launches, stage timing."""

"""Material reconstruction: mesh colors (shared-sample layout), the material model the
reconstruction loop swaps in, material labels from masks, optimisation stages, export."""

"""One interface per instrument kind, and the transports that speak to hardware."""

"""Paper metrics, tallies, statistics and the PDF report builder (paper §VII)."""

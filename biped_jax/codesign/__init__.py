"""Co-design of gear ratio and link masses with the gait: problem and plots."""

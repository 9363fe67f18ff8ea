"""The batch job: planning work, workers, and the store that writes labels."""

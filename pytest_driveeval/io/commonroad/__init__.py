"""CommonRoad XML scenarios (2018b and 2020a), read without commonroad-io."""

import pytest

from rwalk.assets import load_model

FLAT = "model/world_flat.xml"
TRAIN = "model/world_train.xml"


@pytest.fixture(scope="session")
def flat_model():
    return load_model(FLAT)


@pytest.fixture(scope="session")
def train_model():
    return load_model(TRAIN)

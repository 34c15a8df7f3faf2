"""The command service (middle level): ``Common`` and ``Middle`` of JARA_ARM, motion queue, settings."""

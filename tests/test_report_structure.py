"""The report's sections (issue 24): each one class with ``process_data`` and ``get_statistic``, the shape of
evo's metric classes. The length of functions is tests/test_code_shape.py's."""


def test_each_report_section_is_one_class():
    from slamobs.pipeline.evaluation import sections

    classes = [
        c
        for c in vars(sections).values()
        if isinstance(c, type) and issubclass(c, sections.Section) and c is not sections.Section
    ]
    assert {c.__name__ for c in classes} == {
        "ApeSection",
        "ApeByAlignmentSection",
        "RpeSection",
        "DriftSection",
        "SegmentErrorsSection",
        "TimeOffsetSection",
        "LandmarkSection",
        "BiasSection",
        "ConvergenceSection",
        "UncertaintySection",
    }
    for cls in classes:
        assert callable(getattr(cls, "process_data", None)) and callable(cls.get_statistic), cls.__name__

from setuptools import find_packages, setup

PACKAGE = "msfsu_evaluation"

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
    ],
    # suites.ROUTE_FILES: every route version; abilities.ABILITIES_FILE: the per-ability scenarios
    package_data={"msfsu_evaluation.closed_loop": ["routes*.json", "abilities.json"]},
    zip_safe=False,
    maintainer="MSFSU team",
    maintainer_email="msfsu@example.com",
    description="Evaluation of the MSFSU node graph: open-loop bag replay against the bag's ground truth, closed-loop benchmark in the simulator.",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "msfsu-eval-bag = msfsu_evaluation.bag_eval:main",
            "msfsu-benchmark = msfsu_evaluation.closed_loop.cli:main",
            "msfsu-benchmark-report = msfsu_evaluation.closed_loop.report:main",
            "msfsu-bag-video = msfsu_evaluation.bag_video:main",
            "msfsu-int8-recipe = msfsu_evaluation.deploy.recipe:main",
            "msfsu-gate = msfsu_evaluation.deploy.gate:main",
            "msfsu-dataset-report = msfsu_evaluation.dataset_report:main",
            "msfsu-results-blocks = msfsu_evaluation.reports.blocks:main",
            "msfsu-prose-figures = msfsu_evaluation.reports.prose_figures:main",
            "msfsu-regenerate-reports = msfsu_evaluation.reports.regenerate:main",
            "msfsu-revision-change = msfsu_evaluation.reports.revision_change:main",
            "msfsu-graph-change = msfsu_evaluation.reports.graph_change:main",
            "msfsu-model-v3-release = msfsu_evaluation.reports.release:main",
            "msfsu-rules-change = msfsu_evaluation.reports.rules_change:main",
            "msfsu-node-parameters = msfsu_evaluation.reports.node_parameters:main",
            "msfsu-model-v3 = msfsu_evaluation.pipelines.model_v3:main",
            "msfsu-waiting = msfsu_evaluation.pipelines.waiting:main",
            "msfsu-default-model = msfsu_evaluation.pipelines.default_model:main",
        ],
    },
)

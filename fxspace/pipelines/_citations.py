"""The four papers fxspace implements, cited from the texts in ``../shared/papers/``.

One table (`CITATIONS`, keyed like the reproduction pages) that the generated
reproduction pages read (`fxspace.pipelines._docs.render`); README.md and the four guides
``docs/guides/paper-*.md`` carry the same lines (``tests/test_api_tour.py`` checks that
they agree). Authors and titles are as printed in each paper's header; venue and year
only where the header prints them, and said so where it does not (nothing is guessed).
"""

from __future__ import annotations

__all__ = ["CITATIONS"]

#: Markdown, one line each: authors (affiliation where printed), "title" (the original
#: title where the printed one is not English), language, venue and year as printed.
CITATIONS: dict[str, str] = {
    "kim-jung": (
        'Sung-Ho Kim and Moon-Ryul Jung, "Hierarchical Visualization of the Space of '
        'Facial Expressions" (얼굴 표정공간의 계층적 가시화), in Korean with an English '
        "abstract. Venue and year as printed in the paper's header: no venue is printed; "
        "received 5 February 2004, review completed 9 August 2004."
    ),
    "hirose-higuchi": (
        "Kei Hirose (Osaka University) and Tomoyuki Higuchi (The Institute of Statistical "
        'Mathematics), "フェイシャル・モーション・キャプチャーデータに基づく 3Dキャラクターの'
        '表情付け" (no English title is printed; in English, giving 3-D characters their '
        "expressions from facial motion-capture data), in Japanese with an English abstract. "
        "Venue and year as printed in the paper's header: neither is printed."
    ),
    "ha-han": (
        "DongWook Ha and JungHyun Han (Korea University), \"Decoupled Parametric Motion "
        'Synthesis Based on Blending" (상 · 하체 분리 매개화를 통한 블렌딩 기반의 모션 합성), '
        "in Korean with an English abstract. Venue and year as printed in the paper's "
        "header: neither is printed (the acknowledgement names the 2007 Culture Content "
        "Technology programme)."
    ),
    "park-kang-kwon": (
        "Hyunah Park, Daeun Kang and Taesoo Kwon (Hanyang University), \"삼각형 메쉬로 "
        '이루어진 3D 모델의 변형을 위한 IK 계산 가속화" (no English title is printed; in '
        "English, accelerating IK computation for deforming 3-D models made of triangle "
        "meshes), in Korean with an English abstract. Venue and year as printed in the "
        "paper's header: Journal of the Korea Computer Graphics Society, 2021 (received "
        "11 August 2021, published online 30 November 2021; the figure labels read "
        "jkcgs-27-5-1, i.e. vol. 27, no. 5)."
    ),
}
